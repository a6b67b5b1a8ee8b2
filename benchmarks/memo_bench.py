"""How many of a profile's rewrites the fast route repeats from its memory, on one pass of a real stream.

proxy_bench.py replays a few seconds of telemetry over and over, so after the first pass the route's rewrite
memory (mitm_proxy/README.md, "The fast path") answers every targeted frame. A live stream brings new readings
all the time; each reading the route has not seen goes up to Python once and teaches it. This script sends each
stream ONCE through a real ``secuav-proxy`` (in this process, on loopback, the compiled fast path) with the
proxy_bench rewrite profile (a bias on the DISTANCE_SENSOR ids that make up about 10 % of the frames) and
prints, from the proxy's own counters (``endpoints.<vehicle>.fast``, docs/interfaces.md):

- the frames the profile rewrote, and how many of them the route rewrote in C;
- the distinct keys among the targeted frames (payload less its time field): the floor of what must go up.

Streams: ArduPilot SITL's recorded flight (tests/data/ardupilot-copter-guided.tlog) and ``--record-s`` seconds
of ``secuav-sim wall_hover`` at 1x, recorded first (as proxy_bench.py records it).

    .venv/bin/python benchmarks/memo_bench.py [--record-s 60]
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import tempfile
from pathlib import Path

from proxy_bench import frames_of, load_tlog, record_telemetry, rewrite_ids, write_rewrite_profile

from mavframe import codec
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.net import native_udp

TLOG = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardupilot-copter-guided.tlog"
DISTANCE_SENSOR = 132
_TIME = codec.field_span(DISTANCE_SENSOR, "time_boot_ms") or (0, 0)
_ID = codec.byte_field(DISTANCE_SENSOR, "id") or 0


def distinct_keys(frames: list[bytes], ids: list[int]) -> int:
    """Targeted DISTANCE_SENSOR frames told apart as the route's key tells them (the time field left out)."""
    keys = set()
    for f in frames:
        if f[0] != 0xFD or f[7] | f[8] << 8 | f[9] << 16 != DISTANCE_SENSOR:
            continue
        payload = bytearray(f[10 : 10 + f[1]])
        if (payload[_ID] if len(payload) > _ID else 0) not in ids:
            continue
        off, n = _TIME
        payload[off : off + n] = bytes(min(n, max(0, len(payload) - off)))
        keys.add((f[5], f[6], bytes(payload).rstrip(b"\0")))  # sysid, compid, payload
    return len(keys)


async def one_pass(frames: list[bytes], profile: Path) -> dict[str, int]:
    """Send every frame once, one per datagram, through an in-process proxy; its counters at the end."""
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 1024 * 1024)
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}", ground=[f"udpout://127.0.0.1:{sink.getsockname()[1]}"])
    loop = asyncio.get_running_loop()
    got = 0
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none", profile=profile)) as proxy:
            ep = proxy.links[0].vehicle
            if not isinstance(ep, native_udp.NativeUdpEndpoint):
                raise SystemExit("the compiled fast path is not built (bash scripts/setup.sh) or is turned off")
            for i, f in enumerate(frames):
                vehicle.sendto(f, ("127.0.0.1", port))
                if i % 200 == 199:  # let the proxy and the sink keep up: this measures shares, not speed
                    while got < i - 100:
                        await asyncio.wait_for(loop.sock_recv(sink, 65535), 10.0)
                        got += 1
            while got < len(frames):
                await asyncio.wait_for(loop.sock_recv(sink, 65535), 10.0)
                got += 1
            snap = proxy.stats_snapshot()[1]
            down = snap["downlink"]
            return {"frames": down["frames_in"], "rewritten": down["rewritten"],
                    "in_c": snap["endpoints"][ep.name]["fast"]["rewritten"]}  # fmt: skip
    finally:
        vehicle.close()
        sink.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--record-s", type=float, default=60.0, help="seconds of secuav-sim telemetry to record (1x)")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # the proxy's own notes (a true copy left on the wire) are not this script's
    streams = {f"ArduPilot SITL ({TLOG.name})": load_tlog(TLOG)}
    print(f"recording {args.record_s:g} s of secuav-sim wall_hover ...", flush=True)
    streams[f"secuav-sim wall_hover ({args.record_s:g} s at 1x)"] = record_telemetry(args.record_s)
    print(f"{'stream':45} {'frames':>7} {'ids':>6} {'rewritten':>9} {'in C':>7} {'share':>6} {'keys':>6}")
    for name, datagrams in streams.items():
        frames = [f for d in datagrams for f in frames_of(d)]
        ids, _ = rewrite_ids(frames)
        with tempfile.TemporaryDirectory() as work:
            res = asyncio.run(one_pass(frames, write_rewrite_profile(Path(work) / "rewrite10.yaml", ids)))
        share = res["in_c"] / res["rewritten"] if res["rewritten"] else 0.0
        print(f"{name:45} {res['frames']:7d} {ids!s:>6} {res['rewritten']:9d} {res['in_c']:7d} {share:6.1%} "
              f"{distinct_keys(frames, ids):6d}")  # fmt: skip
    print("rewritten: frames the profile changed (the proxy's downlink counter); in C: of them, rewritten by the "
          "route from its memory; keys: distinct targeted frames less their time field (each goes up to Python at "
          "least once)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

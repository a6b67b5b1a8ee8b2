"""What per-endpoint rules add to the send path (issue 14 target: <= 2 us per frame with filters on).

Sends one-frame datagrams (ATTITUDE, the commonest telemetry) through a real
``udpout`` endpoint on loopback, alternating: no rules (the baseline), a deny
rule the frame passes, a deny rule that drops it, and a listen-only endpoint's
uplink path. Prints microseconds per frame and the difference to the baseline
measured in the same round. Figures only, no assertions.

    .venv/bin/python benchmarks/routes_bench.py [--n 50000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import statistics
import time

from pymavlink.dialects.v20 import common as mavlink2

from mitm_proxy.net.endpoints import UdpEndpoint
from mitm_proxy.net.rules import EndpointRules, FrameFilter
from secuav_common.urls import parse_endpoint


async def _cost(rules: EndpointRules, frame: bytes, n: int, port: int) -> float:
    ep = await UdpEndpoint(parse_endpoint(f"udpout://127.0.0.1:{port}"), "bench", rules=rules).open()
    try:
        send = ep.send
        t0 = time.perf_counter()
        for _ in range(n):
            send(frame)
        return (time.perf_counter() - t0) / n * 1e6
    finally:
        ep.close()


async def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=50_000)
    p.add_argument("--repeat", type=int, default=5)
    args = p.parse_args()
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 16)  # let the kernel drop; we time the sender
    port = sink.getsockname()[1]
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mav.attitude_encode(1000, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav)
    cases = {
        "no rules": EndpointRules(),
        "deny, frame passes": EndpointRules(down=FrameFilter(deny=["DISTANCE_SENSOR"])),
        "deny, frame dropped": EndpointRules(down=FrameFilter(deny=["ATTITUDE"])),
        "allow list + sysid, passes": EndpointRules(
            down=FrameFilter(allow=["ATTITUDE", "HEARTBEAT"], deny_sysid=[7])
        ),
    }
    times: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(args.repeat):
        for name, rules in cases.items():
            times[name].append(await _cost(rules, frame, args.n, port))
    base = statistics.median(times["no rules"])
    print(f"{'case':28s} {'us/frame':>9s} {'added':>7s}")
    for name, values in times.items():
        med = statistics.median(values)
        print(f"{name:28s} {med:9.2f} {med - base:+7.2f}")
    sink.close()


if __name__ == "__main__":
    asyncio.run(main())

"""Does a flood of MQTT traffic slow the proxy's forwarding? (issue 15: the embedded broker's place)

Runs the real ``secuav-proxy`` twice: with ``--broker none`` (the baseline: the
flood goes to a broker in its own process, so it competes for the CPU but not
for the proxy's loop) and with ``--broker embedded`` (the broker the proxy
starts on 127.0.0.1:1883, which the flood hits). Each time it streams ATTITUDE
frames through the proxy at ``--rate`` per second, first quietly, then while
``--clients`` MQTT clients publish ``--flood-rate`` messages/s to a topic nobody reads,
and prints the added latency (p50, p99, max) and the frames lost, with the
ratio of the flooded p99 to the baseline's. Figures only, no assertions.

    .venv/bin/python benchmarks/broker_flood_bench.py [--rate 1000] [--seconds 8] [--clients 2] [--flood-rate 3000]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from secuav_common.broker import port_in_use

ROOT = Path(__file__).resolve().parents[1]
MQTT = 1883


def _free_udp() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def flood_client(port: int, rate: float, size: int) -> None:
    """A client that publishes ``size``-byte QoS 0 messages, ``rate`` a second (0: as fast as it can), in a child
    process."""
    import aiomqtt

    async def run() -> None:
        async with aiomqtt.Client("127.0.0.1", port) as client:
            client.pending_calls_threshold = 1000  # 50 in flight by design
            payload = b"x" * size
            start, sent = time.monotonic(), 0
            while True:
                await asyncio.gather(*(client.publish("secuav/flood", payload) for _ in range(50)))
                sent += 50
                if rate > 0 and (ahead := start + sent / rate - time.monotonic()) > 0:
                    await asyncio.sleep(ahead)

    asyncio.run(run())


def measure(tx: socket.socket, rx: socket.socket, vehicle: int, rate: float, seconds: float) -> tuple[list[float], int]:
    """Send ``rate`` frames/s for ``seconds`` into the proxy; latencies (ms) of those that came out, and the sent.

    ``tx`` and ``rx`` are the vehicle's and the ground's sockets for the whole case: the proxy follows the
    first vehicle address it hears, and a ground port that closes between phases would be reported unreachable."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    sent: dict[int, float] = {}
    got: dict[int, float] = {}
    done = threading.Event()

    def receive() -> None:
        while not done.is_set():
            try:
                data = rx.recv(2048)
            except TimeoutError:
                continue
            now = time.perf_counter()
            if len(data) >= 14 and data[0] == 0xFD and data[7] == 30:  # ATTITUDE: index in time_boot_ms
                got[struct.unpack_from("<I", data, 10)[0]] = now

    thread = threading.Thread(target=receive, daemon=True)
    thread.start()
    n = int(rate * seconds)
    start = time.perf_counter()
    for i in range(n):
        due = start + i / rate
        if (wait := due - time.perf_counter()) > 0:
            time.sleep(wait)  # sleeping, not spinning: the receiving thread needs the GIL
        frame = mav.attitude_encode(i + 1, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav)
        sent[i + 1] = time.perf_counter()
        tx.sendto(frame, ("127.0.0.1", vehicle))
    time.sleep(0.5)
    done.set()
    thread.join()
    return [(got[i] - sent[i]) * 1e3 for i in sent if i in got], n


def summary(lat: list[float], sent: int) -> str:
    if not lat:
        return f"nothing came through ({sent} sent)"
    q = statistics.quantiles(lat, n=100)
    return f"p50 {q[49]:6.3f}  p99 {q[98]:7.3f}  max {max(lat):7.2f} ms  lost {sent - len(lat)}/{sent}"


def run_case(broker: str, args: argparse.Namespace, env: dict[str, str]) -> dict[str, list[float]]:
    vehicle, ground = _free_udp(), _free_udp()
    proxy = subprocess.Popen([sys.executable, "-m", "mitm_proxy", "--broker", broker, "-q",
                              "--vehicle", f"udpin://127.0.0.1:{vehicle}", "--ground", f"udpout://127.0.0.1:{ground}"],
                             cwd=ROOT, env=env)  # fmt: skip
    floods: list[subprocess.Popen[bytes]] = []
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", ground))
    rx.settimeout(0.2)
    try:
        deadline = time.monotonic() + 30
        while not port_in_use("127.0.0.1", MQTT):
            if time.monotonic() > deadline:
                raise RuntimeError("no broker on 1883")
            time.sleep(0.1)
        time.sleep(1.0)
        measure(tx, rx, vehicle, args.rate, 1.0)  # warm up: the proxy's first peer, caches
        quiet = measure(tx, rx, vehicle, args.rate, args.seconds)
        flood = [sys.executable, __file__, "--flood-client", str(MQTT), "--flood-rate",
                 str(args.flood_rate / args.clients), "--payload", str(args.payload)]
        floods = [subprocess.Popen(flood, cwd=ROOT, env=env, stderr=subprocess.DEVNULL) for _ in range(args.clients)]
        time.sleep(1.0)
        flooded = measure(tx, rx, vehicle, args.rate, args.seconds)
        print(f"  {broker:9s} quiet:   {summary(*quiet)}")
        print(f"  {broker:9s} flooded: {summary(*flooded)}", flush=True)
        return {"quiet": quiet[0], "flooded": flooded[0]}
    finally:
        for f in floods:
            f.terminate()
            f.wait(5)
        proxy.terminate()
        proxy.wait(10)
        tx.close()
        rx.close()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--seconds", type=float, default=8.0)
    p.add_argument("--clients", type=int, default=2)
    p.add_argument("--flood-rate", type=float, default=3000.0,
                   help="MQTT messages/s of all clients together (0: as fast as they can; on 2 cores that measures "
                        "CPU contention, not the broker's place)")
    p.add_argument("--payload", type=int, default=128, help="bytes per flood message (128)")
    p.add_argument("--flood-client", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.flood_client:
        flood_client(args.flood_client, args.flood_rate, args.payload)
        return 0
    if port_in_use("127.0.0.1", MQTT):
        print(f"port {MQTT} is in use: stop that broker first (the proxy's embedded broker needs it)", file=sys.stderr)
        return 1
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    print(f"{args.rate:.0f} ATTITUDE frames/s through secuav-proxy; {args.clients} MQTT clients publishing "
          f"{args.flood_rate:.0f} messages/s of {args.payload} bytes to the broker")
    standalone = subprocess.Popen([sys.executable, "-m", "secuav_common.broker_main", "127.0.0.1", str(MQTT)],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=ROOT, env=env)  # fmt: skip
    try:
        assert standalone.stdout is not None and standalone.stdout.readline().strip() == b"ready"
        base = run_case("none", args, env)
    finally:
        standalone.terminate()
        standalone.wait(10)
    while port_in_use("127.0.0.1", MQTT):
        time.sleep(0.1)
    embedded = run_case("embedded", args, env)
    ratio = statistics.quantiles(embedded["flooded"], n=100)[98] / statistics.quantiles(base["flooded"], n=100)[98]
    print(f"flooded p99, embedded broker / broker in its own process (--broker none): {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

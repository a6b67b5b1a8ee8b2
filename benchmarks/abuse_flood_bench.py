"""Forwarding latency while one client abuses the proxy (issue 28: no client can slow the others).

Runs the real ``secuav-proxy`` with one vehicle (UDP), a UDP ground station
whose latency is measured, a ``tcpin`` listen-only ground endpoint open to
anyone, and a broker in its own process. It streams ATTITUDE frames at
``--rate`` per second and prints the added latency (p50, p99, max) and the
frames lost, quietly and then under each abuse, with the ratio of each p99 to
the quiet one measured in the same run:

- ``tcp garbage``: a client on the tcpin endpoint sends ``fd 00`` as fast as
  it can, connecting again each time the proxy drops it;
- ``idle tcp clients``: ``--idle-clients`` clients connect to the tcpin
  endpoint and never read what it sends them;
- ``request flood``: an MQTT client sends a valid ~55 kB profile to
  ``secuav/v1/attack/set`` ``--request-rate`` times a second.

Figures only, no assertions.

    .venv/bin/python benchmarks/abuse_flood_bench.py [--rate 500] [--seconds 6] [--idle-clients 200]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from broker_flood_bench import _free_udp, measure, summary

from secuav_common.broker import port_in_use

ROOT = Path(__file__).resolve().parents[1]


def _free_tcp() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def garbage_flood(port: int, stop: Any) -> None:
    chunk = b"\xfd\x00" * 32768
    while not stop.is_set():
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2) as sock:
                while not stop.is_set():
                    sock.sendall(chunk)
        except OSError:
            time.sleep(0.05)  # dropped by the proxy: connect again


@contextlib.contextmanager
def idle_clients(port: int, n: int) -> Iterator[None]:
    socks = []
    for _ in range(n):
        with contextlib.suppress(OSError):
            sock = socket.socket()
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.connect(("127.0.0.1", port))
            socks.append(sock)
    try:
        yield
    finally:
        for sock in socks:
            sock.close()


def request_flood(port: int, rate: float, stop: Any) -> None:
    import asyncio

    import aiomqtt

    rules = [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": k % 6, "field": "current_distance"},
              "kind": "bias", "offset_m": round(0.001 * k, 3)} for k in range(420)]  # fmt: skip

    async def run() -> None:
        async with aiomqtt.Client("127.0.0.1", port) as client:
            k = 0
            while not stop.is_set():
                body = json.dumps({"request_id": f"flood-{k}", "name": f"flood-{k}", "rules": rules}).encode()
                await client.publish("secuav/v1/attack/set", body, qos=0)
                k += 1
                await asyncio.sleep(1.0 / rate)

    asyncio.run(run())


@contextlib.contextmanager
def in_process(target: Callable[..., None], *args: object) -> Iterator[None]:
    """Run an abuser in its own process, so that it does not share this one's interpreter with the measurement."""
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.Event()
    proc = ctx.Process(target=target, args=(*args, stop), daemon=True)
    proc.start()
    try:
        time.sleep(1.5)
        yield
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.kill()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=500.0, help="ATTITUDE frames/s through the proxy")
    p.add_argument("--seconds", type=float, default=6.0, help="per case")
    p.add_argument("--idle-clients", type=int, default=200)
    p.add_argument("--request-rate", type=float, default=20.0)
    args = p.parse_args()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    mqtt, tcp_port, vehicle, ground = _free_tcp(), _free_tcp(), _free_udp(), _free_udp()
    broker = subprocess.Popen([sys.executable, "-m", "secuav_common.broker_main", "127.0.0.1", str(mqtt)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=ROOT, env=env)  # fmt: skip
    proxy = None
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", ground))
    rx.settimeout(0.2)
    try:
        assert broker.stdout is not None and broker.stdout.readline().strip() == b"ready"
        proxy = subprocess.Popen([sys.executable, "-m", "mitm_proxy", "-q", "--broker", f"mqtt://127.0.0.1:{mqtt}",
                                  "--vehicle", f"udpin://127.0.0.1:{vehicle}",
                                  "--ground", f"udpout://127.0.0.1:{ground}",
                                  "--ground", f"tcpin://127.0.0.1:{tcp_port}?listen_only=true"],
                                 cwd=ROOT, env=env)  # fmt: skip
        deadline = time.monotonic() + 30
        while not port_in_use("127.0.0.1", tcp_port):
            if time.monotonic() > deadline:
                raise RuntimeError("the proxy did not open its tcpin endpoint")
            time.sleep(0.1)
        print(f"{args.rate:.0f} ATTITUDE frames/s through secuav-proxy, {args.seconds:g} s per case")
        measure(tx, rx, vehicle, args.rate, 1.0)  # warm up
        cases: list[tuple[str, contextlib.AbstractContextManager[None]]] = [
            ("quiet", contextlib.nullcontext()),
            ("tcp garbage", in_process(garbage_flood, tcp_port)),
            (f"{args.idle_clients} idle tcp clients", idle_clients(tcp_port, args.idle_clients)),
            (f"request flood {args.request_rate:g}/s", in_process(request_flood, mqtt, args.request_rate)),
        ]
        base_p99 = None
        for name, abuse in cases:
            with abuse:
                lat, sent = measure(tx, rx, vehicle, args.rate, args.seconds)
            p99 = statistics.quantiles(lat, n=100)[98] if len(lat) > 1 else float("nan")
            base_p99 = p99 if base_p99 is None else base_p99
            print(f"  {name:24s} {summary(lat, sent)}  p99 x{p99 / base_p99:5.1f}", flush=True)
    finally:
        for proc in (proxy, broker):
            if proc is not None:
                proc.terminate()
                proc.wait(10)
        tx.close()
        rx.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Soak a running ``secuav-proxy``: a steady stream for minutes while the attack profile is swapped every second.

    .venv/bin/python benchmarks/soak_bench.py [--minutes 10] [--rate 2000] [--swap-s 1.0] [--loop uvloop]

The proxy runs as a real process with one link and a real broker (amqtt in a
child process, as the proxy itself runs it). This script is the vehicle and
the ground station on loopback, and an MQTT client that publishes a new
profile to ``secuav/v1/attack/set`` every ``--swap-s`` seconds, alternating a
DISTANCE_SENSOR bias, a scale and no attack (a payload with only a ``request_id``), each with a ``request_id``, and
counts the proxy's acknowledgements on ``secuav/v1/attack/state``.

Every frame is a DISTANCE_SENSOR numbered by its ``time_boot_ms``, so a frame
is found at the ground whether or not the attack rewrote it. Printed at the end:
frames sent and received (the goal: none lost), swaps acknowledged ok, the
latency sender -> proxy -> receiver (p50, p99, max, same monotonic clock), the
proxy's RSS after a warm-up and at the end (the goal: growth under 10 MB), its
CPU time per frame. A progress line every 30 s.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import aiomqtt
from proxy_bench import cpu_s, free_port, pct, rss_kb  # the same measures as the speed benchmark
from pymavlink.dialects.v20 import common as mavlink

from mavframe.frames import split
from secuav_common.broker import EmbeddedBroker

BIN = Path(sys.executable).parent
WARMUP_S = 20.0  # RSS is taken as the baseline after this (imports, caches and first profiles settled)
PROFILES = [
    {"name": "soak-bias", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                     "kind": "bias", "offset_m": 0.5}]},
    {"name": "soak-scale", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                      "kind": "scale", "factor": 1.2}]},
    None,
]  # fmt: skip
_BOOT_MS = struct.Struct("<I")  # DISTANCE_SENSOR's first payload field, the frame number here


def _free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Stream:
    """Sender and receiver threads; frame k leaves at t0 + k / rate."""

    def __init__(self, veh_port: int, gcs_sock: socket.socket, rate: float, seconds: float) -> None:
        self.veh_port, self.gcs, self.rate, self.seconds = veh_port, gcs_sock, rate, seconds
        self.sent_at: dict[int, float] = {}
        self.got_at: dict[int, float] = {}
        self.duplicates = 0
        self.done = threading.Event()
        self.stop_rx = threading.Event()

    def send(self) -> None:
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        total = int(self.rate * self.seconds)
        t0 = time.monotonic()
        for k in range(1, total + 1):
            due = t0 + k / self.rate
            ahead = due - time.monotonic()
            if ahead > 0.0005:
                time.sleep(ahead)
            frame = mav.distance_sensor_encode(k, 10, 4000, 250, 0, 0, 0, 0).pack(mav)
            self.sent_at[k] = time.monotonic()
            sock.sendto(frame, ("127.0.0.1", self.veh_port))
        self.done.set()

    def receive(self) -> None:
        self.gcs.settimeout(0.2)
        while not self.stop_rx.is_set():
            try:
                data = self.gcs.recv(65536)
            except TimeoutError:
                continue
            now = time.monotonic()
            for header, raw in split(data).frames:
                if header.msgid != mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR:
                    continue
                k = _BOOT_MS.unpack_from(raw, 10)[0]
                if k in self.got_at:
                    self.duplicates += 1
                self.got_at[k] = now


async def _swapper(port: int, every_s: float, stream: Stream, acks: dict[str, int]) -> None:
    async with aiomqtt.Client("127.0.0.1", port) as client:
        await client.subscribe("secuav/v1/attack/state")

        async def count() -> None:
            async for message in client.messages:
                state = json.loads(bytes(message.payload))
                if str(state.get("request_id", "")).startswith("soak-"):
                    acks["ok" if state.get("ok") else "refused"] += 1

        counter = asyncio.create_task(count())
        k = 0
        try:
            while not stream.done.is_set():
                profile = PROFILES[k % len(PROFILES)]
                body = {**(profile or {}), "request_id": f"soak-{k}"}  # only a request_id: clear the attack
                await client.publish("secuav/v1/attack/set", json.dumps(body).encode())
                acks["sent"] += 1
                k += 1
                await asyncio.sleep(every_s)
            await asyncio.sleep(2.0)  # the last acknowledgements
        finally:
            counter.cancel()


async def run(args: argparse.Namespace) -> int:
    veh, gcs_port, mqtt = free_port(), free_port(), _free_tcp_port()
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", gcs_port))
    gcs.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    seconds = args.minutes * 60.0
    # The proxy's log goes to a file, never to a pipe nobody reads while it runs: a full pipe (64 KiB, about 465
    # profile swaps of log lines) blocks the proxy's writes and with them its whole event loop.
    log = tempfile.TemporaryFile()  # noqa: SIM115  (read and closed once the proxy has exited, below)
    async with EmbeddedBroker(port=mqtt, process=True):
        proxy = subprocess.Popen(
            [str(BIN / "secuav-proxy"), "--broker", f"mqtt://127.0.0.1:{mqtt}", "--loop", args.loop,
             "--vehicle", f"udpin://127.0.0.1:{veh}", "--ground", f"udpout://127.0.0.1:{gcs_port}"],
            stdout=subprocess.DEVNULL, stderr=log, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        try:
            await asyncio.sleep(3.0)  # binds its ports and connects to the broker
            stream = Stream(veh, gcs, args.rate, seconds)
            threads = [threading.Thread(target=stream.receive, daemon=True),
                       threading.Thread(target=stream.send, daemon=True)]  # fmt: skip
            for t in threads:
                t.start()
            acks = {"sent": 0, "ok": 0, "refused": 0}
            swaps = asyncio.create_task(_swapper(mqtt, args.swap_s, stream, acks))
            t0 = time.monotonic()
            cpu0 = cpu_s(proxy.pid)
            rss_warm = 0
            next_report = 30.0
            while not stream.done.is_set():
                await asyncio.sleep(1.0)
                elapsed = time.monotonic() - t0
                if not rss_warm and elapsed >= WARMUP_S:
                    rss_warm = rss_kb(proxy.pid)
                if elapsed >= next_report:
                    next_report += 30.0
                    rss_mb = rss_kb(proxy.pid) / 1024
                    print(f"  {elapsed:4.0f} s: {len(stream.sent_at)} sent, {len(stream.got_at)} received, "
                          f"{acks['ok']} swaps ok, RSS {rss_mb:.1f} MB", file=sys.stderr)  # fmt: skip
            await swaps
            await asyncio.sleep(1.0)
            stream.stop_rx.set()
            threads[0].join()
            cpu = cpu_s(proxy.pid) - cpu0
            rss_end = rss_kb(proxy.pid)
            alive = proxy.poll() is None
        finally:
            proxy.send_signal(signal.SIGINT)
            proxy.wait(timeout=20)
            log.seek(0)
            err = log.read()
            log.close()
    sent = len(stream.sent_at)
    lost = sorted(set(stream.sent_at) - set(stream.got_at))
    lat = [(stream.got_at[k] - t) * 1e3 for k, t in stream.sent_at.items() if k in stream.got_at]
    print(f"soak: {args.minutes:g} min at {args.rate:,.0f} frames/s ({args.loop}), "
          f"profile swapped every {args.swap_s:g} s")  # fmt: skip
    print(f"frames: {sent} sent, {sent - len(lost)} received, {len(lost)} lost"
          + (f" (first lost: {lost[:5]})" if lost else "") + f", {stream.duplicates} duplicated")  # fmt: skip
    print(f"swaps: {acks['sent']} published, {acks['ok']} acknowledged ok, {acks['refused']} refused")
    print(f"latency ms: p50 {pct(lat, 0.5):.3f}  p99 {pct(lat, 0.99):.3f}  p99.9 {pct(lat, 0.999):.3f}  "
          f"max {max(lat, default=float('nan')):.3f}")  # fmt: skip
    print(f"proxy RSS: {rss_warm / 1024:.1f} MB after {WARMUP_S:.0f} s, {rss_end / 1024:.1f} MB at the end "
          f"(growth {(rss_end - rss_warm) / 1024:+.1f} MB); CPU {cpu / max(sent, 1) * 1e6:.1f} us per frame; "
          f"alive at the end: {alive}, exit code after SIGINT {proxy.returncode}")  # fmt: skip
    if proxy.returncode not in (0, -signal.SIGINT):
        print("proxy stderr tail: " + " | ".join(err.decode(errors="replace").strip().splitlines()[-3:]))
    return 0 if not lost and acks["ok"] == acks["sent"] else 1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--rate", type=float, default=2000.0, help="frames per second, one per datagram")
    p.add_argument("--swap-s", type=float, default=1.0, help="seconds between profile swaps")
    p.add_argument("--loop", choices=("uvloop", "asyncio"), default="uvloop")
    return asyncio.run(run(p.parse_args()))


if __name__ == "__main__":
    sys.exit(main())

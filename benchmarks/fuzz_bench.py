"""Fuzz a running ``secuav-proxy`` with random and mutated datagrams mixed with valid frames.

    .venv/bin/python benchmarks/fuzz_bench.py [--datagrams 1000000] [--rate 20000] [--seed 1]

The proxy runs as a real process (``secuav-proxy --broker none``) with one link;
this script is the vehicle, on loopback, and also the ground station that reads
what comes out. Datagrams, drawn with a fixed seed:

- valid: one DISTANCE_SENSOR frame each, made unique by its ``time_boot_ms``;
- random bytes (1 to 280 of them);
- mutated frames: a valid frame with a flipped byte, cut short, with a signed
  flag and a short signature, doubled headers, or a valid frame behind garbage;
- oversized: 8 to 64 KB of crafted bytes full of magic bytes and headers
  (``--oversized-share`` of the hostile ones, 0.2 % by default).

Printed: datagrams sent, valid frames sent and how many came out byte for byte
and in order (the goal is all of them), whether the proxy is still alive, its
own count of bad input by reason, and the loss-free rate it held. Paced at
``--rate`` datagrams per second so that loopback socket buffers, not the proxy,
never decide the outcome.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from mavframe.frames import split

BIN = Path(sys.executable).parent


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _kernel_drops(port: int) -> int | None:
    """Datagrams the kernel dropped for a full receive buffer on the loopback UDP socket bound to ``port``
    (Linux ``/proc/net/udp``), or None where that is not known: it says which side lost what."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        if int(fields[1].split(":")[1], 16) == port:
            return int(fields[-1])
    return None


def _valid(mav: mavlink.MAVLink, k: int) -> bytes:
    return mav.distance_sensor_encode(k & 0xFFFFFFFF, 10, 4000, 250, 0, 0, 0, 0).pack(mav)


def _hostile(rng: random.Random, mav: mavlink.MAVLink, k: int, oversized_share: float) -> bytes:
    kind = 5 if rng.random() < oversized_share else rng.randrange(5)
    frame = bytearray(_valid(mav, 0x80000000 | k))  # never equal to a valid frame of this run
    if kind == 0:
        return rng.randbytes(rng.randint(1, 280))
    if kind == 1:
        frame[rng.randrange(1, len(frame))] ^= rng.randint(1, 255)
        return bytes(frame)
    if kind == 2:
        return bytes(frame[: rng.randrange(1, len(frame))])
    if kind == 3:
        frame[2] |= 0x01  # signed flag, then a signature cut short
        return bytes(frame) + rng.randbytes(rng.randrange(0, 13))
    if kind == 4:
        return bytes(frame[:10]) * rng.randint(2, 20)
    return rng.randbytes(rng.randint(8_000, 65_000)).replace(b"\x00", b"\xfd")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--datagrams", type=int, default=1_000_000)
    p.add_argument("--rate", type=float, default=20_000.0, help="datagrams per second")
    p.add_argument("--valid-share", type=float, default=0.5)
    p.add_argument("--oversized-share", type=float, default=0.002,
                   help="share of hostile datagrams that are 8-64 KB of crafted bytes (each costs the proxy "
                   "milliseconds: at 1 %% of 20 k/s they alone exceed what one core can split)")  # fmt: skip
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    veh, gcs = _free_port(), _free_port()
    ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground.bind(("127.0.0.1", gcs))
    ground.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    ground.settimeout(0.5)
    proxy = subprocess.Popen(
        [str(BIN / "secuav-proxy"), "--broker", "none", "--vehicle", f"udpin://127.0.0.1:{veh}",
         "--ground", f"udpout://127.0.0.1:{gcs}", "--stats-interval", "5"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    received: list[bytes] = []
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            try:
                data = ground.recv(70_000)
            except TimeoutError:
                continue
            received.extend(raw for _h, raw in split(data).frames)

    reader = threading.Thread(target=receive, daemon=True)
    reader.start()
    time.sleep(1.5)  # the proxy binds its port
    rng = random.Random(args.seed)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent_valid: list[bytes] = []
    t0 = time.perf_counter()
    period = 1.0 / args.rate
    for k in range(args.datagrams):
        if rng.random() < args.valid_share:
            frame = _valid(mav, k)
            sent_valid.append(frame)
            sender.sendto(frame, ("127.0.0.1", veh))
        else:
            sender.sendto(_hostile(rng, mav, k, args.oversized_share), ("127.0.0.1", veh))
        if k % 1000 == 999:
            ahead = t0 + (k + 1) * period - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            if k % 100_000 == 99_999:
                print(f"  {k + 1} datagrams sent", file=sys.stderr)
    elapsed = time.perf_counter() - t0
    time.sleep(2.0)
    stop.set()
    reader.join()
    drops = (_kernel_drops(veh), _kernel_drops(gcs))
    alive = proxy.poll() is None
    proxy.send_signal(signal.SIGINT)
    _, err = proxy.communicate(timeout=20)
    valid_set = set(sent_valid)
    out_valid = [f for f in received if f in valid_set]
    in_order = out_valid == sent_valid
    print(f"datagrams sent: {args.datagrams} in {elapsed:.1f} s ({args.datagrams / elapsed:,.0f}/s)")
    print(f"valid frames: {len(sent_valid)} sent, {len(out_valid)} forwarded byte for byte "
          f"({'all, in order' if in_order else 'MISSING OR REORDERED'})")  # fmt: skip
    print(
        f"other frames out: {len(received) - len(out_valid)} (unknown-id frames found in the noise, which a MAVLink "
        "router forwards, and any CRC-valid look-alikes)"
    )
    if drops[0] is not None:
        print(f"dropped by the kernel for a full receive buffer: {drops[0]} at the proxy's vehicle socket (the proxy "
              f"fell behind), {drops[1]} at this script's ground socket (its reader fell behind)")  # fmt: skip
    print(f"proxy alive at the end: {alive}; exit code after SIGINT: {proxy.returncode}")
    tail = err.decode(errors="replace").strip().splitlines()[-3:]
    if tail:
        print("proxy stderr tail: " + " | ".join(tail))


if __name__ == "__main__":
    main()

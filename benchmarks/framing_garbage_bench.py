"""What hostile bytes on a stream cost the framing: CPU per MB, and whether it stays linear.

A TCP or serial peer can send anything. The proxy cuts the stream into whole
frames (``StreamFramer.feed``) and then splits each piece (``split``); both walk
the bytes looking for magic bytes. This prints, for several hostile patterns and
growing sizes, the CPU time per MB of ``feed`` + ``split`` (the stream path, in
4 kB reads as a socket would give them) and of one ``split`` over the whole
buffer (the worst case: one huge read), each as a ratio to a clean stream of
real frames of the same size measured in the same run. Linear framing means
the per-MB figure of a pattern does not grow with the size.

Patterns: ``fd00`` (the review's flood: every other byte a v2 magic with bad
flags, no v1 magic anywhere), ``fe_only`` (v1 magic bytes and nothing else),
``unknown_hdrs`` (overlapping v2 headers of an unknown message id, each of
which must be checked for a known frame inside it) and ``random``.

    .venv/bin/python benchmarks/framing_garbage_bench.py [--sizes 16,64,256,1024] [--repeat 3]
"""

from __future__ import annotations

import argparse
import random
import struct
import time
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from mavframe.frames import StreamFramer, split

READ = 4096  # bytes per read, as a socket would hand them over


def clean(size: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mav.attitude_encode(1000, 0.01, -0.02, 1.5, 0.001, 0.002, 0.003).pack(mav)
    return (frame * (size // len(frame) + 1))[:size]


def unknown_headers(size: int) -> bytes:
    # A v2 header of msgid 0xABCDEF (no dialect knows it) claiming 255 bytes of payload, every 12 bytes:
    # each candidate covers the next ~20 candidates.
    hdr = struct.pack("<BBBBBBBHB", 0xFD, 255, 0, 0, 0, 1, 1, 0xCDEF, 0xAB) + b"\x00\x00"
    return (hdr * (size // len(hdr) + 1))[:size]


PATTERNS: dict[str, Callable[[int], bytes]] = {
    "fd00": lambda size: b"\xfd\x00" * (size // 2),
    "fe_only": lambda size: b"\xfe" * size,
    "unknown_hdrs": unknown_headers,
    "random": lambda size: random.Random(size).randbytes(size),
}


def stream_cost(data: bytes) -> float:
    framer = StreamFramer()
    t0 = time.process_time()
    for i in range(0, len(data), READ):
        piece = framer.feed(data[i : i + READ])
        if piece:
            split(piece)
    return time.process_time() - t0


def whole_cost(data: bytes) -> float:
    t0 = time.process_time()
    split(data)
    return time.process_time() - t0


def best(fn: Callable[[bytes], float], data: bytes, repeat: int) -> float:
    return min(fn(data) for _ in range(repeat))


def row(name: str, size: int, stream_s_mb: float, stream_x: float, whole_s_mb: float, whole_x: float) -> None:
    stream = f"{stream_s_mb * 1e3:>13.1f} {stream_x:>8.1f}"
    print(f"{name:<13} {size // 1024:>6} {stream} {whole_s_mb * 1e3:>16.1f} {whole_x:>8.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="16,64,256,1024", help="buffer sizes in kB")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sizes = [int(s) * 1024 for s in args.sizes.split(",")]
    print(f"{'pattern':<13} {'kB':>6} {'stream ms/MB':>13} {'x clean':>8} {'one split ms/MB':>16} {'x clean':>8}")
    for size in sizes:
        base = clean(size)
        mb = size / 2**20
        base_stream = best(stream_cost, base, args.repeat) / mb
        base_whole = best(whole_cost, base, args.repeat) / mb
        row("clean", size, base_stream, 1.0, base_whole, 1.0)
        for name, make in PATTERNS.items():
            data = make(size)
            s = best(stream_cost, data, args.repeat) / mb
            w = best(whole_cost, data, args.repeat) / mb
            row(name, size, s, s / base_stream, w, w / base_whole)


if __name__ == "__main__":
    main()

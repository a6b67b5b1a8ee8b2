"""Record what a link received and what it forwarded, as .tlog files plus an index.

``DIR/original.tlog`` holds every valid frame as it arrived, ``DIR/forwarded.tlog``
every frame as it left (both directions, interleaved in time), in the format
pymavlink's ``mavlogdump.py`` and MAVExplorer read: for each frame an 8-byte
big-endian count of microseconds since the UNIX epoch, then the frame bytes.
A delayed frame is stamped with the time it is due to leave.

``DIR/index.json`` is a JSON array, one object per frame a stage changed,
injected, delayed or dropped: ``{"index": n, "original": k, "msgid": m,
"direction": "downlink"|"uplink", "changed": bool, "injected": bool,
"dropped": bool, "delay_s": d, "notes": [...]}``. ``index`` counts frames in
forwarded.tlog from 0 (``null`` for a dropped frame), ``original`` counts frames
in original.tlog (``null`` for an injected one), and ``notes`` name the rules
that acted (``attack:<profile>:rules[<i>]``). It is written as frames go
(memory stays flat on long runs) and closed by :meth:`Recorder.close`; all
files are flushed at least every second.
"""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

from mitm_proxy.packet import Header, Packet

__all__ = ["Recorder"]

_STAMP = struct.Struct(">Q")


class Recorder:
    """Writes one link's recording into ``directory`` (created if missing)."""

    def __init__(self, directory: str | Path, link: int = 0, *, wall_clock: Callable[[], float] = time.time) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.link = link
        self._clock = wall_clock
        self._original: IO[bytes] = open(self.directory / "original.tlog", "wb")  # noqa: SIM115 - closed in close()
        self._forwarded: IO[bytes] = open(self.directory / "forwarded.tlog", "wb")  # noqa: SIM115
        self._index: IO[str] = open(self.directory / "index.json", "w", encoding="utf-8")  # noqa: SIM115
        self._index.write("[")
        self._n_index = 0
        self.original_count = 0
        self.forwarded_count = 0
        self.closed = False
        self._flushed_at = self._clock()

    FLUSH_EVERY_S = 1.0  # a crash or SIGKILL loses at most about this much of the recording

    def _stamp(self, delay_s: float = 0.0) -> bytes:
        now = self._clock()
        if now - self._flushed_at >= self.FLUSH_EVERY_S:
            self._flushed_at = now
            self.flush()
        return _STAMP.pack(int((now + delay_s) * 1e6))

    def original(self, frames: list[tuple[Header, bytes]]) -> int:
        """Frames as received (one datagram's worth); returns the index of the first in original.tlog."""
        first = self.original_count
        stamp = self._stamp()
        self._original.write(b"".join(stamp + raw for _, raw in frames))
        self.original_count += len(frames)
        return first

    def forwarded_frames(self, frames: list[tuple[Header, bytes]]) -> None:
        """Frames forwarded untouched (the fast path)."""
        stamp = self._stamp()
        self._forwarded.write(b"".join(stamp + raw for _, raw in frames))
        self.forwarded_count += len(frames)

    def forwarded(
        self,
        data: bytes,
        msgid: int,
        pkt: Packet | None = None,
        delay_s: float = 0.0,
        original: int | None = None,
    ) -> None:
        """One forwarded frame; ``pkt`` when a stage handled it, so the index can say what happened."""
        self._forwarded.write(self._stamp(delay_s) + data)
        if pkt is not None and (pkt.changed or pkt.injected or delay_s > 0.0):
            self._entry(self.forwarded_count, original, msgid, pkt, delay_s)
        self.forwarded_count += 1

    def dropped(self, msgid: int, pkt: Packet, original: int | None) -> None:
        """A frame a stage dropped: only the index records it."""
        self._entry(None, original, msgid, pkt, 0.0, dropped=True)

    def _entry(
        self, index: int | None, original: int | None, msgid: int, pkt: Packet, delay_s: float, dropped: bool = False
    ) -> None:
        entry = {
            "index": index,
            "original": None if pkt.injected else original,
            "msgid": msgid,
            "direction": pkt.direction.value,
            "changed": pkt.changed,
            "injected": pkt.injected,
            "dropped": dropped,
            "delay_s": round(delay_s, 6),
            "notes": list(pkt.notes),
        }
        self._index.write(("\n" if self._n_index == 0 else ",\n") + json.dumps(entry))
        self._n_index += 1

    def flush(self) -> None:
        for f in (self._original, self._forwarded, self._index):
            f.flush()

    def close(self) -> None:
        """Finish index.json and close the files; safe to call twice."""
        if self.closed:
            return
        self.closed = True
        self._index.write("\n]\n")
        for f in (self._original, self._forwarded, self._index):
            f.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

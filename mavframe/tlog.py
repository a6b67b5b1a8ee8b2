"""The .tlog telemetry log: what QGroundControl, MAVProxy and SecUAV's recorders write.

Each entry is an 8-byte big-endian count of microseconds since the UNIX epoch,
then one MAVLink frame as it was on the wire; nothing else (no header, no
index), which is why pymavlink's ``mavlogdump.py`` and MAVExplorer read any of
them. :func:`stamp` makes the 8 bytes; :func:`read` walks a log entry by entry.

Reading checks every frame as :func:`mavframe.frames.split` does (CRC with the
message's CRC_EXTRA). A damaged entry (a bad CRC, a cut-off last frame, bytes
that are not a log) is skipped, counted in :attr:`TlogReader.skipped`, and the
walk resumes at the next place where a stamp is followed by a valid frame of a
known message, so one bad byte costs one entry, never the rest of the log. A
frame of a message id the dialect does not know has no CRC to check; it is
kept when the next entry starts right after it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Final, NamedTuple

from mavframe.frames import CRC_EXTRA, MagicCursor, frame_at
from mavframe.packet import Header

__all__ = ["STAMP_LEN", "TlogEntry", "TlogReader", "read", "stamp"]

STAMP_LEN: Final = 8
_STAMP = struct.Struct(">Q")


def stamp(t_s: float) -> bytes:
    """The 8-byte entry prefix for wall-clock time ``t_s`` (seconds since the UNIX epoch)."""
    return _STAMP.pack(int(t_s * 1e6))


class TlogEntry(NamedTuple):
    t_s: float  # the entry's stamp, seconds since the UNIX epoch
    header: Header
    raw: bytes  # the frame, byte for byte


class TlogReader:
    """Iterate the entries of one log held in memory; ``skipped`` counts damaged stretches passed over."""

    def __init__(self, data: bytes) -> None:
        self.data = bytes(data)
        self.skipped = 0

    def __iter__(self) -> Iterator[TlogEntry]:
        data = self.data
        n = len(data)
        magic = MagicCursor(data, n)  # one per pass: a log with no v1 frame is searched for 0xFE once, not per resync
        i = 0
        while i + STAMP_LEN < n:
            found = frame_at(data, i + STAMP_LEN)
            if found is None:
                self.skipped += 1
                i = self._resync(i + 1, magic)
                continue
            header, end = found
            if header.msgid not in CRC_EXTRA and end < n and frame_at(data, end + STAMP_LEN) is None:
                # An unknown id has no CRC to check: believe it only if the next entry starts where it ends.
                self.skipped += 1
                i = self._resync(i + 1, magic)
                continue
            yield TlogEntry(_STAMP.unpack_from(data, i)[0] * 1e-6, header, data[i + STAMP_LEN : end])
            i = end
        if i < n:  # a tail too short to hold a stamp and a frame
            self.skipped += 1

    def _resync(self, lo: int, magic: MagicCursor) -> int:
        """The next entry start at or after ``lo``: a stamp followed by a valid frame of a known message."""
        data = self.data
        n = len(data)
        k = magic.at_or_after(lo + STAMP_LEN)
        while k < n:
            found = frame_at(data, k)
            if found is not None and found[0].msgid in CRC_EXTRA:
                return k - STAMP_LEN
            k = magic.at_or_after(k + 1)
        return n


def read(path: str | Path) -> TlogReader:
    """A reader over the log at ``path`` (read whole: a 30-minute flight at 1 kHz is about 60 MB)."""
    return TlogReader(Path(path).read_bytes())

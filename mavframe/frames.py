"""Split a UDP datagram into MAVLink frames without decoding them.

The proxy must forward every valid frame byte for byte and must not pay for
decoding frames nobody targets, so this module only *peeks*: one ``struct``
unpack of the header, one CRC over the frame (with the message's CRC_EXTRA,
the per-message seed byte that MAVLink adds so that a frame of the wrong
dialect fails its check). Nothing here allocates a pymavlink message.

Resynchronisation follows what autopilots do: a candidate that fails its CRC
is skipped by *one byte*, not by its claimed length, so garbage whose bytes
happen to look like a header can never swallow the next real frame. Frames of
message ids our dialect does not know cannot be CRC-checked; they are kept
(and counted) unless a CRC-valid known frame starts inside them, in which case
the "unknown frame" was garbage that only looked like a header. The limit of
this: garbage shaped like an unknown-id header can hide a following frame of
another unknown id (neither can be checked); known frames are never hidden.

Skipped bytes are reported once per run with the reason found at its start:
``garbage`` (no magic byte), ``truncated`` (the frame runs past the datagram),
``bad_crc``, ``bad_flags`` (v2 incompatibility flags other than signing, which
MAVLink says must be refused) and ``bad_length`` (a v1 frame longer than its
message, impossible as v1 has no extensions); ``text`` is a run of printable
ASCII lines where garbage would be (ArduPilot SITL prints its boot messages,
"Init ArduCopter ...", on the same serial link as its MAVLink).

Measured on the 2-core bench machine (benchmarks/proxy_core_bench.py): ~3 µs
per frame, about 4x pymavlink's ``parse_buffer``; hostile 64 KB datagrams of
overlapping fake headers still go at ~2-6 MB/s.

The dialect is pymavlink's ``ardupilotmega`` (a superset of ``common`` with the
same CRC_EXTRA for every common message), so traffic from PX4 and ArduPilot
is checked alike.
"""

from __future__ import annotations

import struct
from bisect import bisect_left
from dataclasses import dataclass, field
from typing import Final

from fastcrc import crc16
from pymavlink.dialects.v20 import ardupilotmega as dialect

from mavframe.packet import Header

__all__ = [
    "BAD_CRC",
    "BAD_FLAGS",
    "BAD_LENGTH",
    "CRC_EXTRA",
    "GARBAGE",
    "SIGNATURE_LEN",
    "TEXT",
    "TRUNCATED",
    "MagicCursor",
    "SplitResult",
    "StreamFramer",
    "crc_of",
    "frame_at",
    "next_magic",
    "split",
    "tiles",
]

STX_V1: Final = 0xFE
STX_V2: Final = 0xFD
IFLAG_SIGNED: Final = 0x01
SIGNATURE_LEN: Final = 13  # link id (1) + timestamp (6) + signature (6)
V1_HEADER_LEN: Final = 6
V2_HEADER_LEN: Final = 10
CRC_LEN: Final = 2

# Reasons for skipped bytes, as they appear in ``SplitResult.bad`` and in the stats.
GARBAGE: Final = "garbage"  # bytes that do not start with a MAVLink magic byte
TRUNCATED: Final = "truncated"  # a header whose frame runs past the end of the datagram
BAD_CRC: Final = "bad_crc"  # a complete frame of a known message whose CRC does not match
BAD_FLAGS: Final = "bad_flags"  # a v2 header with incompatibility flags we cannot honour
BAD_LENGTH: Final = "bad_length"  # a v1 header claiming more payload than its message has

TEXT: Final = "text"  # a run of printable ASCII lines, such as an autopilot's boot messages on its serial port

CRC_EXTRA: Final[dict[int, int]] = {msgid: cls.crc_extra for msgid, cls in dialect.mavlink_map.items()}

_V1_MAX_LEN: Final[dict[int, int]] = {msgid: cls.unpacker.size for msgid, cls in dialect.mavlink_map.items()}
_EXTRA_BYTES: Final[dict[int, bytes]] = {msgid: bytes((extra,)) for msgid, extra in CRC_EXTRA.items()}
_mcrf4xx = crc16.mcrf4xx
_V1 = struct.Struct("<BBBBBB").unpack_from  # stx len seq sysid compid msgid
_V2 = struct.Struct("<BBBBBBBHB").unpack_from  # stx len incompat compat seq sysid compid msgid_lo msgid_hi
_CRC = struct.Struct("<H").unpack_from


@dataclass(slots=True)
class SplitResult:
    """What one datagram held: its valid frames in order and why bytes were skipped.

    ``bad`` has one reason per skipped run of bytes; ``unknown`` counts the kept
    frames whose message id the dialect does not know (not CRC-checked).
    """

    frames: list[tuple[Header, bytes]] = field(default_factory=list)
    bad: list[str] = field(default_factory=list)
    unknown: int = 0

    @property
    def clean(self) -> bool:
        """True when the datagram was nothing but valid frames."""
        return not self.bad


def next_magic(data: bytes, lo: int, hi: int) -> int:
    """Where the next MAVLink magic byte (v1 or v2) is in ``data[lo:hi]``, or ``hi``: two C-level searches."""
    a = data.find(b"\xfd", lo, hi)
    b = data.find(b"\xfe", lo, hi)
    if a < 0:
        return hi if b < 0 else b
    return a if b < 0 or a < b else b


class MagicCursor:
    """The next magic byte at or after a position that only moves forward, over one buffer.

    :func:`next_magic` searches for both magic bytes up to ``hi``; called from every
    position of a buffer full of one magic byte and none of the other, it rescans to
    the end each time (quadratic: 256 kB of ``fd 00`` took over a second). The cursor
    remembers where each byte was last found, so each byte of the buffer is searched
    at most once per magic byte, whatever the buffer holds.
    """

    __slots__ = ("_data", "_fd", "_fe", "_n")

    def __init__(self, data: bytes, n: int) -> None:
        self._data = data
        self._n = n
        self._fd = -1  # where 0xFD was last found (n: none left); below the asked position: search again
        self._fe = -1

    def at_or_after(self, lo: int) -> int:
        """Where the next magic byte is in ``data[lo:]``, or ``n``; ``lo`` never decreases between calls."""
        fd = self._fd
        if fd < lo:
            fd = self._data.find(b"\xfd", lo)
            self._fd = fd = self._n if fd < 0 else fd
        fe = self._fe
        if fe < lo:
            fe = self._data.find(b"\xfe", lo)
            self._fe = fe = self._n if fe < 0 else fe
        return fd if fd < fe else fe


def crc_of(frame: bytes | bytearray | memoryview, end: int, crc_extra: int) -> int:
    """MAVLink's X.25 CRC of ``frame[1:end]`` followed by ``crc_extra`` (``end`` = start of the CRC field)."""
    return _mcrf4xx(bytes((crc_extra,)), _mcrf4xx(bytes(frame[1:end]), 0xFFFF))


def _candidate(data: bytes, i: int, n: int) -> tuple[Header, int, str | None]:
    """Peek the frame starting at ``data[i]`` (a magic byte).

    Returns the header, the frame's end and ``None`` if it is a valid frame, or a
    reason why it is not (then header and end are meaningless).
    """
    if data[i] == STX_V2:
        if n - i < V2_HEADER_LEN:
            return _NO_HEADER, 0, TRUNCATED
        _, plen, incompat, _compat, seq, sysid, compid, lo, hi = _V2(data, i)
        if incompat & ~IFLAG_SIGNED:
            return _NO_HEADER, 0, BAD_FLAGS
        signed = bool(incompat & IFLAG_SIGNED)
        crc_at = i + V2_HEADER_LEN + plen
        end = crc_at + CRC_LEN + (SIGNATURE_LEN if signed else 0)
        header = Header(2, lo | hi << 16, sysid, compid, seq, plen, incompat, signed)
    else:
        if n - i < V1_HEADER_LEN:
            return _NO_HEADER, 0, TRUNCATED
        _, plen, seq, sysid, compid, msgid = _V1(data, i)
        size = _V1_MAX_LEN.get(msgid)
        if size is not None and plen > size:  # MAVLink 1 has no extensions: longer is never valid
            return _NO_HEADER, 0, BAD_LENGTH
        crc_at = i + V1_HEADER_LEN + plen
        end = crc_at + CRC_LEN
        header = Header(1, msgid, sysid, compid, seq, plen)
    if end > n:
        return header, end, TRUNCATED
    extra = _EXTRA_BYTES.get(header.msgid)
    if extra is None:
        return header, end, None
    crc = _mcrf4xx(extra, _mcrf4xx(data[i + 1 : crc_at], 0xFFFF))
    if crc != _CRC(data, crc_at)[0]:
        return header, end, BAD_CRC
    return header, end, None


_NO_HEADER: Final = Header(0, -1, 0, 0, 0, 0)


def tiles(data: bytes) -> bool:
    """Whether ``data`` is, by its headers' length fields alone, nothing but back-to-back frames.

    No CRC is checked (:func:`split` does that): this is the cheap test of whether a
    datagram even looks like a sender's frames, one step per frame.
    """
    n = len(data)
    i = 0
    while i < n:
        c = data[i]
        if c == STX_V2 and n - i >= V2_HEADER_LEN:
            i += data[i + 1] + V2_HEADER_LEN + CRC_LEN + (SIGNATURE_LEN if data[i + 2] & IFLAG_SIGNED else 0)
        elif c == STX_V1 and n - i >= V1_HEADER_LEN:
            i += data[i + 1] + V1_HEADER_LEN + CRC_LEN
        else:
            return False
    return i == n


def frame_at(data: bytes, i: int) -> tuple[Header, int] | None:
    """The frame that starts exactly at ``data[i]`` and its end, or ``None`` if none does.

    For readers of formats that say where a frame starts (a .tlog entry); a
    frame of a message id the dialect does not know cannot be CRC-checked and is
    accepted on its header alone.
    """
    if i >= len(data) or data[i] not in (STX_V1, STX_V2):
        return None
    header, end, reason = _candidate(data, i, len(data))
    return None if reason is not None else (header, end)


def _frame_starts_within(data: bytes, lo: int, hi: int, n: int) -> bool:
    """Whether a CRC-valid frame of a known message starts in ``data[lo:hi]`` (a signature block).

    Two C-level searches when the block holds no magic byte, which is nearly always;
    a true signature that happens to hold one passes unless a whole CRC-valid frame starts there.
    """
    j = lo
    while j < hi:
        k = next_magic(data, j, hi)
        if k >= hi:
            return False
        header, _, reason = _candidate(data, k, n)
        if reason is None and header.msgid in CRC_EXTRA:
            return True
        j = k + 1
    return False


class _KnownStarts:
    """Where CRC-valid frames of known messages start in one buffer, found lazily, left to right.

    An unknown-id candidate is kept only if no such frame starts inside it. Each
    position is examined at most once per buffer, so a buffer crafted as
    overlapping fake headers costs one check per magic byte, not one per fake
    header covering it. ``pending`` are the starts of candidates cut off by the
    buffer's end (a stream's next bytes may complete them).
    """

    __slots__ = ("data", "n", "pending", "scanned", "starts")

    def __init__(self, data: bytes, n: int) -> None:
        self.data = data
        self.n = n
        self.scanned = 0  # every position below this has been examined
        self.starts: list[int] = []
        self.pending: list[int] = []

    def _scan_to(self, end: int) -> None:
        data, n = self.data, self.n
        j = self.scanned
        while j < end:
            k = next_magic(data, j, end)
            if k >= end:
                break
            header, _, reason = _candidate(data, k, n)
            if reason is None and header.msgid in CRC_EXTRA:
                self.starts.append(k)
            elif reason == TRUNCATED:
                self.pending.append(k)
            j = k + 1
        self.scanned = max(self.scanned, end)

    def inside(self, start: int, end: int) -> bool:
        """Whether a CRC-valid known frame starts in ``data[start:end]``; ``start`` never decreases."""
        self.scanned = max(self.scanned, start)
        self._scan_to(end)
        return _any_in(self.starts, start, end)

    def pending_inside(self, start: int, end: int) -> bool:
        """Whether a candidate cut off by the buffer's end starts in ``data[start:end]`` (after :meth:`inside`)."""
        return _any_in(self.pending, start, end)


def _any_in(sorted_positions: list[int], start: int, end: int) -> bool:
    i = bisect_left(sorted_positions, start)
    return i < len(sorted_positions) and sorted_positions[i] < end


_TEXT_BYTES: Final = bytes(range(0x20, 0x7F)) + b"\t\n\r"
MIN_TEXT_LEN: Final = 3  # shorter printable runs are as likely noise as words (unless the sender is printing)


def _named(data: bytes, lo: int, hi: int, reason: str, min_text: int = MIN_TEXT_LEN) -> str:
    """``reason`` for the skipped bytes ``data[lo:hi]``, or :data:`TEXT` when they are printable lines, not noise."""
    if reason == GARBAGE and hi - lo >= min_text and not data[lo:hi].translate(None, _TEXT_BYTES):
        return TEXT
    return reason


def split(datagram: bytes, printing: bool = False) -> SplitResult:
    """Find every valid MAVLink v1/v2 frame in ``datagram``, in order; see the module doc.

    ``printing``: the sender was seen printing text lately (the caller keeps that per link), so a printable
    run of any length is text: a console writes progress marks one at a time between frames ("Init
    Gyro***") and a stream's reads cut its lines anywhere ("0 " of "0 0 0 AP_Logger_File ...")."""
    min_text = 1 if printing else MIN_TEXT_LEN
    data = bytes(datagram)
    n = len(data)
    out = SplitResult()
    frames = out.frames
    extras = _EXTRA_BYTES
    i = 0
    skip_start = -1  # start of the current run of skipped bytes
    skip_reason = ""
    known: _KnownStarts | None = None  # made on the first unknown-id candidate
    magic: MagicCursor | None = None  # made on the first byte that is not a frame's start
    while i < n:
        c = data[i]
        if c == STX_V2 and n - i >= V2_HEADER_LEN:
            # The common case inline (unsigned or signed v2 of a known id); anything odd goes to _candidate.
            _, plen, incompat, _compat, seq, sysid, compid, lo, hi = _V2(data, i)
            msgid = lo | hi << 16
            crc_at = i + V2_HEADER_LEN + plen
            end = crc_at + CRC_LEN + (SIGNATURE_LEN if incompat == IFLAG_SIGNED else 0)
            extra = extras.get(msgid)
            if incompat > IFLAG_SIGNED or extra is not None:
                if incompat > IFLAG_SIGNED:
                    reason = BAD_FLAGS
                elif end > n:
                    reason = TRUNCATED
                elif incompat and _frame_starts_within(data, crc_at + CRC_LEN, end, n):
                    # The CRC does not cover the signature: a frame cut short there would swallow the next one.
                    reason = TRUNCATED
                elif _mcrf4xx(extra, _mcrf4xx(data[i + 1 : crc_at], 0xFFFF)) == data[crc_at] | data[crc_at + 1] << 8:
                    if skip_start >= 0:
                        out.bad.append(_named(data, skip_start, i, skip_reason, min_text))
                        skip_start = -1
                    header = Header(2, msgid, sysid, compid, seq, plen, incompat, incompat == IFLAG_SIGNED)
                    frames.append((header, data if (i == 0 and end == n) else data[i:end]))
                    i = end
                    continue
                else:
                    reason = BAD_CRC
                if skip_start < 0:
                    skip_start, skip_reason = i, reason
                i += 1
                continue
        if c in (STX_V2, STX_V1):
            header, end, reason = _candidate(data, i, n)
            if reason is None and header.msgid not in CRC_EXTRA:
                if known is None:
                    known = _KnownStarts(data, n)
                if known.inside(i + 1, end):
                    reason = GARBAGE
            if reason is None:
                if skip_start >= 0:
                    out.bad.append(_named(data, skip_start, i, skip_reason, min_text))
                    skip_start = -1
                if header.msgid not in CRC_EXTRA:
                    out.unknown += 1
                frames.append((header, data if (i == 0 and end == n) else data[i:end]))
                i = end
                continue
            if skip_start < 0:
                skip_start, skip_reason = i, reason
            i += 1
            continue
        # Jump to the next magic byte.
        if skip_start < 0:
            skip_start, skip_reason = i, GARBAGE
        if magic is None:
            magic = MagicCursor(data, n)
        i = magic.at_or_after(i)
    if skip_start >= 0:
        out.bad.append(_named(data, skip_start, n, skip_reason, min_text))
    return out


MAX_FRAME_LEN: Final = V2_HEADER_LEN + 255 + CRC_LEN + SIGNATURE_LEN


class StreamFramer:
    """Cut a byte stream (TCP, serial) into chunks that end where a frame ends.

    A stream may cut a frame anywhere; the splitter above works on whole
    datagrams. ``feed`` returns everything up to the first frame that has not
    fully arrived and holds that tail (never more than one frame,
    two frames' worth) for the next call. The walk resynchronises like
    :func:`split` (a candidate that fails its check moves on by one byte), so
    garbage only delays the frames behind it until enough bytes arrived to
    show it is garbage.
    """

    __slots__ = ("_held",)

    def __init__(self) -> None:
        self._held = b""

    @property
    def held(self) -> int:
        return len(self._held)

    def feed(self, chunk: bytes) -> bytes:
        data = self._held + chunk if self._held else bytes(chunk)
        n = len(data)
        magic = MagicCursor(data, n)
        known: _KnownStarts | None = None
        i = 0
        cut = n
        while i < n:
            k = magic.at_or_after(i)
            if k >= n:
                break
            header, end, reason = _candidate(data, k, n)
            if reason is None and header.msgid not in CRC_EXTRA:
                # An unknown id cannot be checked: as split() does, it is garbage if a known frame starts
                # inside it, and while one that starts inside has not fully arrived, we cannot tell yet.
                if known is None:
                    known = _KnownStarts(data, n)
                if known.inside(k + 1, end):
                    i = k + 1
                    continue
                if known.pending_inside(k + 1, end):
                    reason = TRUNCATED
            if reason == TRUNCATED:
                cut = k
                break
            i = end if reason is None else k + 1
        self._held = data[cut:]
        return data if cut == n else data[:cut]

"""MAVLink 2 frames in and out, over pymavlink's common dialect.

The encoder numbers frames per link (one sequence per vehicle, as PX4 does
per MAVLink instance). The decoder treats each UDP datagram on its own: a
truncated frame at the end of one datagram is counted as malformed rather
than glued to the next datagram, since UDP never splits frames.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from mavframe.frames import split

MAVLink = mavlink.MAVLink
Message = mavlink.MAVLink_message


class Encoder:
    """Packs messages as MAVLink 2 frames from (sysid, compid)."""

    def __init__(self, sysid: int, compid: int = mavlink.MAV_COMP_ID_AUTOPILOT1) -> None:
        self._mav = MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.frames = 0

    @property
    def mav(self) -> MAVLink:
        """The pymavlink object whose ``*_encode`` helpers build messages."""
        return self._mav

    def pack(self, msg: Message) -> bytes:
        mav = self._mav
        frame = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        self.frames += 1
        return frame


@dataclass(slots=True)
class DecodeStats:
    frames: int = 0
    malformed: int = 0  # bad CRC, bad prefix, truncated or undecodable frames


class Decoder:
    """Splits datagrams into decoded messages; garbage is counted, never raised.

    Frames are found and CRC-checked by :func:`mavframe.frames.split`, the same
    splitter the proxy uses: after a corrupt frame the scan resumes one byte
    later, so a valid frame hidden behind garbage in the same datagram is still
    found. Only messages of the common dialect are decoded; others are counted
    as malformed, as a PX4 would ignore them.
    """

    def __init__(self) -> None:
        self._mav = MAVLink(None)
        self.stats = DecodeStats()

    def decode(self, datagram: bytes) -> list[Message]:
        found = split(datagram)
        out: list[Message] = []
        skipped = bool(found.bad)
        for header, raw in found.frames:
            msg = self._decode_frame(raw) if header.msgid in mavlink.mavlink_map else None
            if msg is None:
                skipped = True
                continue
            out.append(msg)
        if skipped:
            self.stats.malformed += 1
        self.stats.frames += len(out)
        return out

    def _decode_frame(self, frame: bytes) -> Message | None:
        # split() checked the CRC and the id is in the common dialect, so pymavlink's decode cannot give an
        # unknown-message placeholder here; it may still raise on a payload it refuses.
        try:
            return self._mav.decode(bytearray(frame))
        except Exception:  # pymavlink raises several types
            return None

"""MAVLink 2 frames in and out, over pymavlink's common dialect.

The encoder numbers frames per link (one sequence per vehicle, as PX4 does
per MAVLink instance). The decoder treats each UDP datagram on its own: a
truncated frame at the end of one datagram is counted as malformed rather
than glued to the next datagram, since UDP never splits frames.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

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

    Scans for frame starts itself instead of using pymavlink's stream parser:
    after a corrupt frame the scan resumes one byte later, so a valid frame
    hidden behind garbage in the same datagram is still found.
    """

    def __init__(self) -> None:
        self._mav = MAVLink(None)
        self.stats = DecodeStats()

    def decode(self, datagram: bytes) -> list[Message]:
        out: list[Message] = []
        buf = bytes(datagram)
        n = len(buf)
        i = 0
        skipped = False
        while i < n:
            magic = buf[i]
            if magic == _V2 and i + 3 <= n:
                length = buf[i + 1] + _V2_OVERHEAD + (_SIGNATURE_LEN if buf[i + 2] & _SIGNED else 0)
            elif magic == _V1 and i + 2 <= n:
                length = buf[i + 1] + _V1_OVERHEAD
            else:
                i += 1
                skipped = True
                continue
            if i + length > n:
                skipped = True  # cut short by the end of the datagram; a later start may still fit
                i += 1
                continue
            msg = self._decode_frame(buf[i : i + length])
            if msg is None:
                skipped = True
                i += 1
                continue
            out.append(msg)
            i += length
        if skipped:
            self.stats.malformed += 1
        self.stats.frames += len(out)
        return out

    def _decode_frame(self, frame: bytes) -> Message | None:
        try:
            msg = self._mav.decode(bytearray(frame))
        except Exception:  # bad CRC, unknown id, short payload: pymavlink raises several types
            return None
        # Ids outside the common dialect decode as MAVLink_unknown without a CRC check: not trustworthy.
        if msg is None or isinstance(msg, _UNTRUSTED):
            return None
        return msg


_UNTRUSTED = (mavlink.MAVLink_unknown, mavlink.MAVLink_bad_data)
_V1, _V2 = 0xFE, 0xFD
_V1_OVERHEAD = 8  # 6 header + 2 CRC
_V2_OVERHEAD = 12  # 10 header + 2 CRC
_SIGNED = 0x01
_SIGNATURE_LEN = 13

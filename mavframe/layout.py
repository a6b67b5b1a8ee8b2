"""Where things sit in a MAVLink frame: message ids, payload start, and the byte offset of a field.

MAVLink orders a message's base fields by size (largest first) and appends its
extensions in declaration order; pymavlink's ``unpacker`` format spells that
wire order, so an offset is read off it once, never typed by hand. Code that
reads a field or two straight from the bytes (the proxy's router, its readings
tap) asks here, and MAVLink 2's truncated trailing zeros are put back by
:func:`payload`.
"""

from __future__ import annotations

import re
import struct
from functools import cache
from typing import Final

from mavframe.codec import BY_NAME, MAVLINK_MAP
from mavframe.frames import V1_HEADER_LEN, V2_HEADER_LEN
from mavframe.packet import Header

V2_MAGIC: Final = 0xFD

# The messages the proxy's stages read by id (docs/interfaces.md#mavlink-mapping-mavlink-2-common-dialect).
GPS_RAW_INT: Final = BY_NAME["GPS_RAW_INT"].id  # 24
ATTITUDE: Final = BY_NAME["ATTITUDE"].id  # 30
LOCAL_POSITION_NED: Final = BY_NAME["LOCAL_POSITION_NED"].id  # 32
GLOBAL_POSITION_INT: Final = BY_NAME["GLOBAL_POSITION_INT"].id  # 33
DISTANCE_SENSOR: Final = BY_NAME["DISTANCE_SENSOR"].id  # 132
HOME_POSITION: Final = BY_NAME["HOME_POSITION"].id  # 242


@cache
def field_offset(msgid: int, name: str) -> int | None:
    """Byte offset of field ``name`` in the payload of message ``msgid``; ``None`` if it has no such field."""
    cls = MAVLINK_MAP.get(msgid)
    if cls is None or name not in cls.ordered_fieldnames:
        return None
    # One token per wire field, in wire order, e.g. "<QIhB20s" -> Q, I, h, B, 20s.
    tokens = re.findall(r"\d*[a-zA-Z]", cls.unpacker.format.lstrip("<"))
    return struct.calcsize("<" + "".join(tokens[: list(cls.ordered_fieldnames).index(name)]))


def offset(msgid: int, name: str) -> int:
    """Byte offset of a field the caller knows the message has; ``KeyError`` naming both if not."""
    found = field_offset(msgid, name)
    if found is None:
        raise KeyError(f"message {msgid} has no field {name!r} in this dialect")
    return found


def offsets_of(name: str) -> dict[int, int]:
    """Every message id that has field ``name``, with the field's payload offset."""
    found = {msgid: field_offset(msgid, name) for msgid in MAVLINK_MAP}
    return {msgid: off for msgid, off in found.items() if off is not None}


TARGET_SYSTEM_OFFSETS: Final = offsets_of("target_system")


def payload_start(frame: bytes) -> int:
    """Where the payload begins: after the 10-byte MAVLink 2 header or the 6-byte MAVLink 1 one."""
    return V2_HEADER_LEN if frame[0] == V2_MAGIC else V1_HEADER_LEN


def payload(frame: bytes, need: int) -> bytes:
    """The payload of a frame, with the zeros MAVLink 2 truncates put back up to ``need`` bytes."""
    start = payload_start(frame)
    body = frame[start : start + frame[1]]
    return body if len(body) >= need else body + bytes(need - len(body))


def target_system(header: Header, frame: bytes) -> int:
    """The frame's ``target_system``, 0 (broadcast) when it has none; v2 payloads may be zero-truncated."""
    offset = TARGET_SYSTEM_OFFSETS.get(header.msgid)
    if offset is None:
        return 0
    start = (V2_HEADER_LEN if header.version == 2 else V1_HEADER_LEN) + offset
    return frame[start] if offset < header.payload_len else 0

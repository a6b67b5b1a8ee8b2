"""MAVLink FTP (FILE_TRANSFER_PROTOCOL): answered, with no files behind it.

PX4 serves files over MAVLink FTP, so ground stations try it first: MAVProxy
fetches ``@PARAM/param.pck``, QGroundControl reads component metadata. The
bench has no file system to offer, so every request gets the answer PX4 gives
for a missing file or an unknown operation, right away: the client falls back
to the plain protocol (PARAM_REQUEST_LIST) instead of waiting out its retries.

Payload layout (``mavlink.io/en/services/ftp.html``): seq u16, session u8,
opcode u8, size u8, req_opcode u8, burst_complete u8, padding u8, offset u32,
data[239].
"""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import common as mavlink

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251
OP_TERMINATE_SESSION, OP_RESET_SESSIONS = 1, 2
OP_ACK, OP_NAK = 128, 129
ERR_UNKNOWN_COMMAND, ERR_FILE_NOT_FOUND = 7, 10
_FILE_OPS = {3, 4, 6, 8, 9, 10, 11, 12, 13, 14, 15, 16}  # list, open, create, remove, ... : "no such file"


def answer(msg: mavlink.MAVLink_file_transfer_protocol_message, mav: mavlink.MAVLink) -> mavlink.MAVLink_message | None:
    """The reply to one FTP request, or None when the payload is too short to be one."""
    raw = bytes(msg.payload)
    if len(raw) < HEADER.size:
        return None
    seq, session, opcode, _size, _req, _burst, _pad, offset = HEADER.unpack_from(raw)
    if opcode in (OP_TERMINATE_SESSION, OP_RESET_SESSIONS):
        reply, data = OP_ACK, b""
    else:
        reply, data = OP_NAK, bytes([ERR_FILE_NOT_FOUND if opcode in _FILE_OPS else ERR_UNKNOWN_COMMAND])
    header = HEADER.pack((seq + 1) & 0xFFFF, session, reply, len(data), opcode, 0, 0, offset)
    payload = (header + data).ljust(PAYLOAD_LEN, b"\0")
    return mav.file_transfer_protocol_encode(0, msg.get_srcSystem(), msg.get_srcComponent(), list(payload))

"""Decode targeted frames, re-pack changed ones, build injected ones.

Only stages call :func:`decode`, and only for message ids they target, so the
cost of pymavlink's decoder is paid on those frames alone. :func:`encode`
returns ``pkt.raw`` for an unchanged packet (byte-exact forwarding); for a
changed one it re-packs the payload from ``pkt.fields`` and writes a header
with the *original* version, flags, sequence, sysid and compid, a fresh CRC
with the message's CRC_EXTRA, and a fresh signature when the original was
signed and a :class:`~mitm_proxy.signing.Signer` is given.

Fields are pymavlink's names and wire units (``current_distance`` in cm,
``lat`` in 1e7 deg); char arrays are ``str`` (as pymavlink gives them), other arrays lists.
Extension bytes our dialect does not know (a newer sender) are kept as they
came.
"""

from __future__ import annotations

import inspect
import struct
from typing import Any, Final

from pymavlink.dialects.v20 import ardupilotmega as dialect

from mitm_proxy.frames import CRC_EXTRA, IFLAG_SIGNED, V1_HEADER_LEN, V2_HEADER_LEN, crc_of
from mitm_proxy.packet import Direction, Header, Packet
from mitm_proxy.signing import Signer

__all__ = ["DecodeError", "EncodeError", "build", "decode", "encode", "message_class", "message_id", "sign_injected"]

MAVLINK_MAP: Final = dialect.mavlink_map
BY_NAME: Final[dict[str, type[dialect.MAVLink_message]]] = {cls.msgname: cls for cls in MAVLINK_MAP.values()}
_INT_TYPES: Final = frozenset(
    {
        "int8_t",
        "uint8_t",
        "int16_t",
        "uint16_t",
        "int32_t",
        "uint32_t",
        "int64_t",
        "uint64_t",
        "uint8_t_mavlink_version",
    }
)
_CRC = struct.Struct("<H")
_V2_HEADER = struct.Struct("<BBBBBBBHB")

# One scratch pymavlink instance: decode() needs it, pack() reads seq/sysid/compid from it.
_MAV: Final = dialect.MAVLink(None, srcSystem=0, srcComponent=0)
_MAV.robust_parsing = True


class DecodeError(ValueError):
    """A frame could not be decoded into fields (unknown id, malformed payload)."""


class EncodeError(ValueError):
    """Fields could not be packed into a frame (missing field, value out of the wire range)."""


def message_class(msgid: int) -> type[dialect.MAVLink_message]:
    cls = MAVLINK_MAP.get(msgid)
    if cls is None:
        raise DecodeError(f"message id {msgid} is not in the dialect")
    return cls


def message_id(name: str) -> int:
    """Message id of a MAVLink message name (``"DISTANCE_SENSOR"`` -> 132)."""
    cls = BY_NAME.get(name)
    if cls is None:
        raise EncodeError(f"unknown MAVLink message {name!r}")
    return int(cls.id)


def decode(pkt: Packet) -> dict[str, Any]:
    """Fill ``pkt.fields`` from ``pkt.raw`` (once) and return it."""
    if pkt.fields is not None:
        return pkt.fields
    cls = message_class(pkt.header.msgid)
    try:
        msg = _MAV.decode(bytearray(pkt.raw))
    except Exception as exc:  # pymavlink raises MAVError, struct.error, TypeError...
        raise DecodeError(f"{cls.msgname}: {exc}") from exc
    pkt.fields = {name: getattr(msg, name) for name in cls.fieldnames}
    return pkt.fields


def _coerce(cls: type[dialect.MAVLink_message], fields: dict[str, Any], raw: bytes | None) -> dict[str, Any]:
    """Field values as pymavlink's ``pack`` wants them (ints for integer fields, bytes for chars).

    pymavlink hands char arrays out as ASCII ``str`` with undecodable bytes
    replaced; an unchanged string is therefore taken back from the original
    frame ``raw`` so that bytes outside ASCII survive a re-pack.
    """
    out: dict[str, Any] = {}
    original: Any = None
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        if name not in fields:
            continue
        v = fields[name]
        if ftype == "char" and isinstance(v, str):
            if raw is not None and original is None:
                original = _MAV.decode(bytearray(raw))
            if original is not None and getattr(original, name, None) == v:
                v = getattr(original, f"_{name}_raw", v.encode())
            else:
                v = v.encode()
        elif ftype in _INT_TYPES:
            if isinstance(v, float):
                if v != v:
                    raise EncodeError(f"{cls.msgname}.{name}: NaN for an integer field")
                v = round(v)
            elif isinstance(v, list):
                v = [round(x) if isinstance(x, float) else x for x in v]
        out[name] = v
    return out


def _payload(cls: type[dialect.MAVLink_message], fields: dict[str, Any], raw: bytes | None = None) -> bytes:
    """The full (untruncated) payload of ``cls`` packed from ``fields`` (``raw``: the frame they came from)."""
    try:
        msg = cls(**_coerce(cls, fields, raw))
        _MAV.seq = 0
        _MAV.srcSystem = 0
        _MAV.srcComponent = 0
        buf = msg.pack(_MAV)
    except EncodeError:
        raise
    except (TypeError, struct.error, ValueError, AttributeError, IndexError) as exc:
        raise EncodeError(f"{cls.msgname}: {exc}") from exc
    payload = buf[V2_HEADER_LEN:-2]
    size = cls.unpacker.size
    return payload + bytes(size - len(payload))


def _frame(header_bytes: bytes, payload: bytes, crc_extra: int) -> bytes:
    body = header_bytes + payload
    return body + _CRC.pack(crc_of(body, len(body), crc_extra))


def _v2_payload(full: bytes) -> bytes:
    plen = len(full)
    while plen > 1 and full[plen - 1] == 0:  # MAVLink 2 truncates trailing zeros
        plen -= 1
    return full[:plen]


def encode(pkt: Packet, signer: Signer | None = None) -> bytes:
    """Wire bytes of ``pkt``: ``raw`` when unchanged, else re-packed (see the module doc)."""
    if not pkt.changed:
        return pkt.raw
    h = pkt.header
    if pkt.fields is None:
        raise EncodeError(f"message id {h.msgid}: changed but never decoded")
    if h.signed and signer is None:
        raise EncodeError(f"message id {h.msgid}: signed frame changed without a signing key")
    cls = MAVLINK_MAP.get(h.msgid)
    if cls is None:
        raise EncodeError(f"message id {h.msgid} is not in the dialect")
    full = _payload(cls, pkt.fields, pkt.raw)
    raw = pkt.raw
    if h.version == 1:
        old = raw[V1_HEADER_LEN : V1_HEADER_LEN + h.payload_len]
        payload = full[: h.payload_len] + old[len(full) :]
        payload += bytes(h.payload_len - len(payload))
        return _frame(raw[:1] + bytes((len(payload),)) + raw[2:V1_HEADER_LEN], payload, cls.crc_extra)
    old = raw[V2_HEADER_LEN : V2_HEADER_LEN + h.payload_len]
    payload = _v2_payload(full + old[len(full) :])
    frame = _frame(raw[:1] + bytes((len(payload),)) + raw[2:V2_HEADER_LEN], payload, cls.crc_extra)
    if h.signed:
        assert signer is not None
        return signer.resign(frame, raw)
    return frame


def sign_injected(frame: bytes, signer: Signer) -> bytes:
    """Sign an unsigned v2 ``frame`` the proxy made: set flag 0x01, fresh CRC, signature on the proxy's link id."""
    if frame[0] != 0xFD or frame[2] & IFLAG_SIGNED:
        raise EncodeError("only an unsigned MAVLink 2 frame can be signed")
    msgid = frame[7] | frame[8] << 8 | frame[9] << 16
    extra = CRC_EXTRA.get(msgid)
    if extra is None:
        raise EncodeError(f"message id {msgid} is not in the dialect")
    body = frame[:2] + bytes((frame[2] | IFLAG_SIGNED,)) + frame[3:-2]
    return signer.sign_new(body + _CRC.pack(crc_of(body, len(body), extra)))


def build(
    message_name: str,
    fields: dict[str, Any],
    *,
    sysid: int,
    compid: int,
    seq: int,
    direction: Direction,
    link: int,
    now_s: float,
    signer: Signer | None = None,
) -> Packet:
    """A MAVLink 2 frame made by the proxy (``injected=True``), signed on the proxy's link id if ``signer``."""
    cls = BY_NAME.get(message_name)
    if cls is None:
        raise EncodeError(f"unknown MAVLink message {message_name!r}")
    missing = [n for n in cls.fieldnames if n not in fields and n not in _extensions(cls)]
    if missing:
        raise EncodeError(f"{message_name}: missing fields {missing}")
    payload = _v2_payload(_payload(cls, fields))
    msgid = int(cls.id)
    flags = IFLAG_SIGNED if signer is not None else 0
    hdr = _V2_HEADER.pack(0xFD, len(payload), flags, 0, seq & 0xFF, sysid, compid, msgid & 0xFFFF, msgid >> 16)
    frame = _frame(hdr, payload, CRC_EXTRA[msgid])
    if signer is not None:
        frame = signer.sign_new(frame)
    header = Header(2, msgid, sysid, compid, seq & 0xFF, len(payload), flags, signer is not None)
    full = {n: fields[n] for n in cls.fieldnames if n in fields}
    return Packet(frame, header, direction, link, now_s, fields=full, injected=True)


def _extensions(cls: type[dialect.MAVLink_message]) -> frozenset[str]:
    """Names of extension fields (they default to zero in pymavlink's constructors)."""
    cached = _EXT_CACHE.get(cls.id)
    if cached is None:
        params = inspect.signature(cls.__init__).parameters
        cached = frozenset(n for n, p in params.items() if p.default is not inspect.Parameter.empty)
        _EXT_CACHE[cls.id] = cached
    return cached


_EXT_CACHE: dict[int, frozenset[str]] = {}

"""Frame builders shared by the frame-layer tests (no tests here; imported as a plain module).

Every frame is packed by pymavlink itself, so the tests compare our splitter and
codec against the reference implementation, not against our own idea of the wire.
"""

from __future__ import annotations

import socket
import struct
from typing import Any

from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mitm_proxy.net import native_udp

DISTANCE_SENSOR = 132
HEARTBEAT = 0
LOCAL_POSITION_NED = 32
GLOBAL_POSITION_INT = 33
TEST_KEY = bytes(range(32))


def mav(sysid: int = 1, compid: int = 1, v1: bool = False, seq: int = 0) -> mavlink.MAVLink:
    m = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    m.seq = seq
    if v1:
        m.WIRE_PROTOCOL_VERSION = "1.0"
    return m


def pack(msg: mavlink.MAVLink_message, m: mavlink.MAVLink | None = None, v1: bool = False) -> bytes:
    m = m or mav()
    data = msg.pack(m, force_mavlink1=v1)
    m.seq = (m.seq + 1) % 256
    return bytes(data)


def distance(cm: int = 523, sensor_id: int = 0, t_ms: int = 1000, **kw: Any) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_distance_sensor_message(t_ms, 10, 4000, cm, 0, sensor_id, 0, 255, **kw)


def heartbeat() -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(2, 12, 129, 393216, 4, 3)


def local_position(x: float = 1.0, y: float = -2.0, z: float = -3.5) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_local_position_ned_message(5000, x, y, z, 0.1, 0.2, 0.3)


def global_position() -> mavlink.MAVLink_message:
    return mavlink.MAVLink_global_position_int_message(5000, 473977418, 85455939, 488000, 3000, 10, -20, 30, 9000)


def statustext(text: bytes = b"hello") -> mavlink.MAVLink_message:
    return mavlink.MAVLink_statustext_message(6, text)


def signed_mav(key: bytes = TEST_KEY, link_id: int = 3, sysid: int = 1, ts: int = 10_000) -> mavlink.MAVLink:
    m = mav(sysid)
    m.signing.secret_key = key
    m.signing.link_id = link_id
    m.signing.sign_outgoing = True
    m.signing.timestamp = ts
    return m


def unknown_frame(msgid: int = 0xABCDE, payload: bytes = b"\x01\x02\x03", seq: int = 7) -> bytes:
    """A v2 frame of a message id no dialect knows (its CRC cannot be checked; any value will do)."""
    hdr = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq, 1, 1, msgid & 0xFFFF, msgid >> 16)
    return hdr + payload + b"\x55\xaa"


def parse_all(data: bytes) -> list[mavlink.MAVLink_message]:
    """What pymavlink's own parser finds in ``data`` (the reference)."""
    m = mavlink.MAVLink(None)
    m.robust_parsing = True
    return list(m.parse_buffer(data) or [])


# -- hypothesis strategies ------------------------------------------------------------------------------

u8 = st.integers(0, 255)
u16 = st.integers(0, 65535)
i16 = st.integers(-32768, 32767)
i32 = st.integers(-(2**31), 2**31 - 1)
f32 = st.floats(-1e6, 1e6, allow_nan=False, width=32)


@st.composite
def messages(draw: st.DrawFn) -> mavlink.MAVLink_message:
    kind = draw(st.sampled_from(["distance", "heartbeat", "local", "global", "statustext", "attitude"]))
    if kind == "distance":
        return mavlink.MAVLink_distance_sensor_message(
            draw(st.integers(0, 2**32 - 1)), draw(u16), draw(u16), draw(u16), draw(st.integers(0, 4)), draw(u8),
            draw(st.integers(0, 100)), draw(u8), draw(f32), draw(f32), [draw(f32) for _ in range(4)], draw(u8),
        )  # fmt: skip
    if kind == "heartbeat":
        return mavlink.MAVLink_heartbeat_message(
            draw(u8), draw(u8), draw(u8), draw(st.integers(0, 2**32 - 1)), draw(u8), 3
        )
    if kind == "local":
        return mavlink.MAVLink_local_position_ned_message(
            draw(st.integers(0, 2**32 - 1)), *[draw(f32) for _ in range(6)]
        )
    if kind == "global":
        return mavlink.MAVLink_global_position_int_message(
            draw(st.integers(0, 2**32 - 1)), draw(i32), draw(i32), draw(i32), draw(i32),
            draw(i16), draw(i16), draw(i16), draw(u16),
        )  # fmt: skip
    if kind == "statustext":
        return mavlink.MAVLink_statustext_message(
            draw(st.integers(0, 7)), draw(st.binary(min_size=1, max_size=50).filter(lambda b: 0 not in b))
        )
    return mavlink.MAVLink_attitude_message(draw(st.integers(0, 2**32 - 1)), *[draw(f32) for _ in range(6)])


@st.composite
def frames(draw: st.DrawFn) -> bytes:
    """One valid frame: v1 or v2, signed or not, any sysid/compid/seq."""
    msg = draw(messages())
    v1 = draw(st.booleans()) and msg.id < 256
    signed = not v1 and draw(st.booleans())
    m = signed_mav(ts=draw(st.integers(1, 2**40))) if signed else mav()
    m.srcSystem, m.srcComponent, m.seq = draw(st.integers(1, 255)), draw(st.integers(1, 255)), draw(u8)
    return pack(msg, m, v1=v1)


garbage = st.binary(min_size=0, max_size=40)


def strict_reader(key: bytes = TEST_KEY) -> mavlink.MAVLink:
    """pymavlink configured like a vehicle with signing on: unsigned or badly signed frames are refused."""
    m = mavlink.MAVLink(None)
    m.signing.secret_key = key
    m.signing.allow_unsigned_callback = lambda _mav, _msgid: False
    return m


def read_strict(data: bytes, key: bytes = TEST_KEY) -> list[Any]:
    m = strict_reader(key)
    out = []
    for b in data:
        try:
            msg = m.parse_char(bytes([b]))
        except mavlink.MAVError:  # "Invalid signature": the frame is refused
            continue
        if msg is not None and msg.get_type() != "BAD_DATA":
            out.append(msg)
    return out


def repacked(frame: bytes, **changed: Any) -> bytes:
    """The Python path's bytes for one ``frame`` with ``changed`` fields (codec.encode, as the pipeline re-packs)."""
    ((header, raw),) = split(frame).frames
    pkt = Packet(raw, header, Direction.DOWNLINK, 0, 0.0)
    codec.decode(pkt).update(changed)
    pkt.changed = True
    return codec.encode(pkt)


def verdict_route(ids: frozenset[int], filters: dict[int, Any], memo: dict[int, tuple[int, int]]) -> Any:
    """A compiled route configured with these wants (``native_udp.route_wants``) and a peer, never drained (no
    socket): its ``verdict``/``learn``/``forget`` are what a proxy's route would do."""
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]  (not built: the caller skips, fast_path)

    r = _fastpath.Route(-1)
    r.configure(False, socket.AF_INET, ("127.0.0.1", 9), [], *native_udp.route_wants(ids, filters, memo))
    return r

"""Decode targeted frames, re-pack changed ones, build injected ones: checked against pymavlink's parser."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavframe import codec
from mavframe.frames import CRC_EXTRA, crc_of, split
from mavframe.packet import Direction, Header, Packet
from mavframe.signing import Signer
from tests.support.frames_support import (
    TEST_KEY,
    distance,
    frames,
    global_position,
    heartbeat,
    mav,
    pack,
    parse_all,
    signed_mav,
    statustext,
    unknown_frame,
)


def packet(frame: bytes) -> Packet:
    ((h, raw),) = split(frame).frames
    return Packet(raw, h, Direction.DOWNLINK, 0, 1.0)


def test_decode_gives_pymavlink_names_in_wire_units() -> None:
    p = packet(pack(distance(cm=523, sensor_id=12)))
    f = codec.decode(p)
    assert f["current_distance"] == 523 and f["id"] == 12 and f["max_distance"] == 4000
    assert p.fields is f
    assert codec.decode(p) is f  # decoded once


def test_decode_v1_and_strings() -> None:
    p = packet(pack(statustext(b"spoofed"), v1=True))
    assert codec.decode(p)["text"] == "spoofed"


def test_decode_unknown_id_raises() -> None:
    with pytest.raises(codec.DecodeError, match="not in the dialect"):
        codec.decode(packet(unknown_frame()))


def test_unchanged_packet_encodes_to_its_raw_object() -> None:
    p = packet(pack(distance()))
    codec.decode(p)
    assert codec.encode(p) is p.raw


@pytest.mark.parametrize("v1", [False, True])
def test_changed_packet_keeps_header_and_gets_a_fresh_crc(v1: bool) -> None:
    frame = pack(global_position(), mav(sysid=7, compid=33, seq=201), v1=v1)
    p = packet(frame)
    codec.decode(p)["lat"] = 473977418 + 1000
    p.changed = True
    out = codec.encode(p)
    (msg,) = parse_all(out)
    assert msg.lat == 473977418 + 1000 and msg.lon == 85455939
    assert (msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq()) == (7, 33, 201)
    assert out[0] == frame[0]
    ((h, _),) = split(out).frames
    assert h.version == (1 if v1 else 2)


def test_v2_trailing_zero_truncation_follows_the_new_values() -> None:
    p = packet(pack(distance(cm=523)))
    f = codec.decode(p)
    f["signal_quality"] = 77  # last byte of the payload: the frame grows
    p.changed = True
    out = codec.encode(p)
    assert out[1] > p.header.payload_len
    assert parse_all(out)[0].signal_quality == 77


def test_float_for_an_integer_field_is_rounded_and_out_of_range_is_an_error() -> None:
    p = packet(pack(distance()))
    codec.decode(p)["current_distance"] = 612.6
    p.changed = True
    assert parse_all(codec.encode(p))[0].current_distance == 613
    p.fields["current_distance"] = 70000  # type: ignore[index]
    with pytest.raises(codec.EncodeError, match="DISTANCE_SENSOR"):
        codec.encode(p)
    p.fields["current_distance"] = float("nan")  # type: ignore[index]
    with pytest.raises(codec.EncodeError, match="NaN"):
        codec.encode(p)


def test_changed_but_never_decoded_is_an_error() -> None:
    p = packet(pack(distance()))
    p.changed = True
    with pytest.raises(codec.EncodeError, match="never decoded"):
        codec.encode(p)


def test_extension_bytes_unknown_to_the_dialect_are_kept() -> None:
    frame = bytearray(pack(heartbeat()))
    # A newer sender appends 3 extension bytes HEARTBEAT does not have in our dialect.
    plen = frame[1]
    body = bytes(frame[:10]) + bytes(frame[10 : 10 + plen]) + b"\x07\x08\x09"
    body = body[:1] + bytes((plen + 3,)) + body[2:]
    full = body + crc_of(body, len(body), CRC_EXTRA[0]).to_bytes(2, "little")
    p = packet(full)
    codec.decode(p)["custom_mode"] = 12345
    p.changed = True
    out = codec.encode(p)
    assert out[1] == plen + 3 and out[10 + plen : 10 + plen + 3] == b"\x07\x08\x09"
    assert split(out).bad == []


def test_signed_frame_changed_without_key_is_refused_and_with_key_is_resigned() -> None:
    frame = pack(distance(), signed_mav(ts=5_000))
    p = packet(frame)
    codec.decode(p)["current_distance"] = 100
    p.changed = True
    with pytest.raises(codec.EncodeError, match="without a signing key"):
        codec.encode(p)
    signer = Signer(TEST_KEY)
    out = codec.encode(p, signer)
    assert Signer(TEST_KEY).verify(out) is None
    assert out[-13] == frame[-13]  # same link id
    assert out[-12:-6] == frame[-12:-6]  # same timestamp keeps the stream monotonic
    assert parse_all(out)[0].current_distance == 100


def test_build_makes_a_v2_frame_pymavlink_reads() -> None:
    p = codec.build(
        "DISTANCE_SENSOR",
        {"time_boot_ms": 5, "min_distance": 10, "max_distance": 4000, "current_distance": 321, "type": 0, "id": 55,
         "orientation": 0, "covariance": 255},
        sysid=2, compid=1, seq=17, direction=Direction.DOWNLINK, link=1, now_s=3.0,
    )  # fmt: skip
    assert p.injected and not p.changed and p.link == 1 and p.rx_s == 3.0
    (msg,) = parse_all(p.raw)
    assert (msg.current_distance, msg.id, msg.get_seq(), msg.get_srcSystem()) == (321, 55, 17, 2)
    assert p.header.msgid == 132 and not p.header.signed


def test_build_errors_name_the_problem() -> None:
    with pytest.raises(codec.EncodeError, match="unknown MAVLink message 'NOPE'"):
        codec.build("NOPE", {}, sysid=1, compid=1, seq=0, direction=Direction.DOWNLINK, link=0, now_s=0.0)
    with pytest.raises(codec.EncodeError, match="missing fields"):
        codec.build("HEARTBEAT", {"type": 2}, sysid=1, compid=1, seq=0, direction=Direction.DOWNLINK, link=0, now_s=0.0)


def test_build_signed_and_sign_injected() -> None:
    fields = {"type": 2, "autopilot": 12, "base_mode": 1, "custom_mode": 0, "system_status": 4, "mavlink_version": 3}
    signer = Signer(TEST_KEY, link_id=9)
    p = codec.build("HEARTBEAT", fields, sysid=1, compid=1, seq=0, direction=Direction.UPLINK, link=0, now_s=0.0,
                    signer=signer)  # fmt: skip
    assert p.header.signed and p.raw[-13] == 9
    assert Signer(TEST_KEY).verify(p.raw) is None
    plain = codec.build("HEARTBEAT", fields, sysid=1, compid=1, seq=0, direction=Direction.UPLINK, link=0, now_s=0.0)
    signed = codec.sign_injected(plain.raw, signer)
    assert Signer(TEST_KEY).verify(signed) is None and split(signed).bad == []
    with pytest.raises(codec.EncodeError):
        codec.sign_injected(signed, signer)


def test_message_id_lookup() -> None:
    assert codec.message_id("DISTANCE_SENSOR") == 132
    with pytest.raises(codec.EncodeError):
        codec.message_id("NOPE")


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames())
def test_fuzz_decode_then_reencode_unchanged_values_is_byte_exact(frame: bytes) -> None:
    p = packet(frame)
    codec.decode(p)
    p.changed = True
    signer = Signer(TEST_KEY) if p.header.signed else None
    assert codec.encode(p, signer) == frame


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 65535), st.integers(0, 255))
def test_fuzz_rewritten_distance_decodes_to_the_new_value(cm: int, sid: int) -> None:
    p = packet(pack(distance(cm=1, sensor_id=sid)))
    codec.decode(p)["current_distance"] = cm
    p.changed = True
    (msg,) = parse_all(codec.encode(p))
    assert (msg.current_distance, msg.id) == (cm, sid)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (a != a and b != b)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


ALL_IDS = sorted(codec.MAVLINK_MAP)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(ALL_IDS), st.data())
def test_fuzz_every_message_decodes_as_pymavlink_does_and_survives_a_repack(msgid: int, data: st.DataObject) -> None:
    cls = codec.MAVLINK_MAP[msgid]
    size = cls.unpacker.size
    payload = data.draw(st.binary(min_size=1, max_size=size))
    hdr = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 1, 1, 1, msgid & 0xFFFF, msgid >> 16)
    body = hdr + payload
    frame = body + crc_of(body, len(body), CRC_EXTRA[msgid]).to_bytes(2, "little")
    p = packet(frame)
    ours = codec.decode(p)
    (ref,) = parse_all(frame)
    assert list(ours) == list(cls.fieldnames)
    for name in cls.fieldnames:
        assert _same(ours[name], getattr(ref, name)), name
    p.changed = True
    again = packet(codec.encode(p))
    back = codec.decode(again)
    assert all(_same(back[n], ours[n]) for n in cls.fieldnames)


def test_every_message_of_the_dialect_round_trips_zero_and_nonzero_payloads() -> None:
    for msgid, cls in codec.MAVLINK_MAP.items():
        size = cls.unpacker.size
        for payload in (bytes(1), bytes((i * 37 + 1) % 97 + 1 for i in range(size))):
            hdr = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 1, 1, 1, msgid & 0xFFFF, msgid >> 16)
            body = hdr + payload
            frame = body + crc_of(body, len(body), CRC_EXTRA[msgid]).to_bytes(2, "little")
            p = packet(frame)
            ours = codec.decode(p)
            (ref,) = parse_all(frame)
            assert all(_same(ours[n], getattr(ref, n)) for n in cls.fieldnames), cls.msgname
            p.changed = True
            assert codec.encode(p) == frame, cls.msgname  # printable payload bytes: byte-exact


def test_careful_path_names_missing_fields_and_bad_array_lengths() -> None:
    p = packet(pack(distance()))
    f = codec.decode(p)
    p.changed = True
    f["quaternion"] = [1.0, 0.0]
    with pytest.raises(codec.EncodeError, match=r"DISTANCE_SENSOR\.quaternion: need 4 values, got 2"):
        codec.encode(p)
    del f["quaternion"]
    with pytest.raises(codec.EncodeError, match="missing field 'quaternion'"):
        codec.encode(p)


def test_unknown_ids_cannot_be_encoded_or_signed() -> None:
    p = packet(unknown_frame())
    p.fields = {}
    p.changed = True
    with pytest.raises(codec.EncodeError, match="not in the dialect"):
        codec.encode(p)
    with pytest.raises(codec.EncodeError, match="not in the dialect"):
        codec.sign_injected(unknown_frame(), Signer(TEST_KEY))


_BYTE_FIELDS = sorted(
    (msgid, name)
    for msgid, cls in codec.MAVLINK_MAP.items()
    for i, name in enumerate(cls.fieldnames)
    if cls.fieldtypes[i] == "uint8_t" and cls.lengths[cls.orders[i]] == 1
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(_BYTE_FIELDS), st.data())
def test_byte_field_is_the_byte_decode_reads(field: tuple[int, str], data: st.DataObject) -> None:
    """The fast route's field filter reads one payload byte (codec.byte_field): for every one-byte unsigned field
    of the dialect, that byte is the field's decoded value, in any payload, truncated or not."""
    msgid, name = field
    offset = codec.byte_field(msgid, name)
    size = codec._layout(codec.message_class(msgid)).size
    assert offset is not None and 0 <= offset < size
    payload = data.draw(st.binary(min_size=0, max_size=size))
    plen = len(payload)
    raw = struct.pack("<BBBBBBBHB", 0xFD, plen, 0, 0, 0, 1, 1, msgid & 0xFFFF, msgid >> 16) + payload + b"\0\0"
    header = Header(2, msgid, 1, 1, 0, plen)  # the CRC is not the point here
    decoded = codec.decode(Packet(raw, header, Direction.DOWNLINK, 0, 0.0))[name]
    assert (payload[offset] if offset < plen else 0) == decoded


def test_byte_field_is_none_for_what_is_not_one_unsigned_byte() -> None:
    assert codec.byte_field(132, "id") == 11
    assert codec.byte_field(132, "current_distance") is None  # uint16
    assert codec.byte_field(132, "quaternion") is None  # an array
    assert codec.byte_field(132, "nope") is None
    assert codec.byte_field(0xABCDE, "id") is None  # not in the dialect

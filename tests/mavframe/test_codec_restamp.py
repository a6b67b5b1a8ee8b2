"""Renumbering a frame (codec.restamp) and taking a signature off (codec.unsigned): pymavlink checks the result."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mavframe import codec
from mavframe.frames import crc_of, split
from tests.support.frames_support import distance, heartbeat, mav, pack, parse_all, signed_mav


@given(st.integers(0, 255), st.integers(0, 255), st.booleans())
def test_a_restamped_frame_is_the_same_message_with_the_new_number(seq: int, new: int, v1: bool) -> None:
    frame = pack(distance(cm=321, sensor_id=4), mav(7, 3, v1=v1, seq=seq), v1=v1)
    out = codec.restamp(frame, new)
    (msg,) = parse_all(out)  # pymavlink checks the CRC
    assert msg.get_seq() == new and msg.get_srcSystem() == 7 and msg.current_distance == 321 and msg.id == 4
    assert len(out) == len(frame) and (out == frame) == (seq == new)


def test_an_unknown_message_keeps_a_valid_crc_when_renumbered() -> None:
    # A message id the dialect lacks, with a CRC made with some CRC_EXTRA the proxy does not know (0x5A).
    body = bytes((0xFD, 3, 0, 0, 9, 1, 1, 0xDE, 0xBC, 0x0A)) + b"\x01\x02\x03"
    frame = body + crc_of(body, len(body), 0x5A).to_bytes(2, "little")
    out = codec.restamp(frame, 10)
    assert out[4] == 10 and int.from_bytes(out[-2:], "little") == crc_of(out, len(out) - 2, 0x5A)


def test_unsigned_takes_the_signature_off_and_the_frame_stays_valid() -> None:
    frame = pack(heartbeat(), signed_mav())
    ((h, _),) = split(frame).frames
    assert h.signed
    out = codec.unsigned(frame)
    ((h2, _),) = split(out).frames  # split checks the CRC
    assert not h2.signed and len(out) == len(frame) - 13 and parse_all(out)[0].custom_mode == 393216
    plain = pack(heartbeat())
    assert codec.unsigned(plain) is plain

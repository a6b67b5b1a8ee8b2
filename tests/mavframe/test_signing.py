"""MAVLink 2 signing: our signatures checked by pymavlink's, pymavlink's checked by ours, and the pipeline policy."""

from __future__ import annotations

import base64
from pathlib import Path

import pytest

from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mavframe.signing import EPOCH_2015_S, Signer, parse_key, timestamp_now
from secuav_common.loading import InputError
from tests.support.frames_support import TEST_KEY, distance, heartbeat, pack, read_strict, signed_mav

DOWN = Direction.DOWNLINK


# -- key files -----------------------------------------------------------------------------------------


def test_key_formats(tmp_path: Path) -> None:
    raw = tmp_path / "raw.key"
    raw.write_bytes(TEST_KEY)
    hexf = tmp_path / "hex.key"
    hexf.write_text(TEST_KEY.hex() + "\n")
    b64 = tmp_path / "b64.key"
    b64.write_text(base64.b64encode(TEST_KEY).decode() + "\n")
    for p in (raw, hexf, b64):
        p.chmod(0o600)
        assert Signer.from_file(p).key == TEST_KEY


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o644])
def test_a_key_others_can_read_is_refused_as_ssh_would(tmp_path: Path, mode: int) -> None:
    key = tmp_path / "link.key"
    key.write_bytes(TEST_KEY)
    key.chmod(mode)
    with pytest.raises(InputError, match=r"link\.key: key: readable by others .*chmod 600"):
        Signer.from_file(key)


def test_bad_keys_name_the_file(tmp_path: Path) -> None:
    short = tmp_path / "short.key"
    short.write_text("abcd")
    short.chmod(0o600)
    with pytest.raises(InputError, match=r"short\.key: key: need 32 raw bytes"):
        Signer.from_file(short)
    with pytest.raises(InputError, match=r"missing\.key: key: cannot read"):
        Signer.from_file(tmp_path / "missing.key")
    with pytest.raises(InputError):
        parse_key(b"z" * 64, "x")  # 64 chars, not hex, not base64 of 32 bytes
    with pytest.raises(InputError):
        parse_key(b"!not base64!", "x")
    with pytest.raises(ValueError, match="32 bytes"):
        Signer(b"short")
    with pytest.raises(ValueError, match="link id"):
        Signer(TEST_KEY, link_id=300)


def test_timestamp_units() -> None:
    assert timestamp_now(EPOCH_2015_S) == 0
    assert timestamp_now(EPOCH_2015_S + 1.0) == 100_000


# -- verification --------------------------------------------------------------------------------------


def test_verify_accepts_pymavlink_signatures_and_refuses_tampering_and_replay() -> None:
    m = signed_mav(ts=1000)
    a, b = pack(distance(), m), pack(heartbeat(), m)
    signer = Signer(TEST_KEY)
    assert signer.verify(a) is None and signer.verify(b) is None
    assert signer.verify(a) == "stale_signature"  # replayed: timestamp not newer on its stream
    tampered = bytearray(pack(distance(), m))
    tampered[-1] ^= 1
    assert Signer(TEST_KEY).verify(bytes(tampered)) == "bad_signature"
    assert Signer(bytes(32)).verify(pack(distance(), m)) == "bad_signature"  # wrong key
    assert signer.verify(pack(distance())) == "bad_signature"  # not signed at all


def test_streams_are_separate_per_link_id() -> None:
    signer = Signer(TEST_KEY)
    assert signer.verify(pack(distance(), signed_mav(link_id=1, ts=500))) is None
    assert signer.verify(pack(distance(), signed_mav(link_id=2, ts=400))) is None  # other stream, older is fine


# -- signing -------------------------------------------------------------------------------------------


def test_resigned_frame_passes_a_strict_pymavlink_reader() -> None:
    frame = pack(distance(cm=500), signed_mav(ts=123_456))
    ((h, raw),) = split(frame).frames
    p = Packet(raw, h, DOWN, 0, 0.0)
    codec.decode(p)["current_distance"] = 900
    p.changed = True
    out = codec.encode(p, Signer(TEST_KEY))
    (msg,) = read_strict(out)
    assert msg.current_distance == 900 and msg.get_signed() and msg.get_link_id() == 3
    assert read_strict(out, key=bytes(32)) == []  # and a reader with another key refuses it


def test_resign_never_reuses_a_timestamp_on_a_stream() -> None:
    signer = Signer(TEST_KEY)
    m = signed_mav(ts=50)
    orig = pack(distance(), m)
    body = orig[:-13]
    first = signer.resign(body, orig)
    second = signer.resign(body, orig)  # same original again: must move forward
    ts = [int.from_bytes(x[-12:-6], "little") for x in (first, second)]
    assert ts == [50, 51]


def test_sign_new_uses_now_and_stays_monotonic() -> None:
    clock = [EPOCH_2015_S + 10.0]
    signer = Signer(TEST_KEY, link_id=7, wall_clock=lambda: clock[0])
    fields = {"type": 2, "autopilot": 12, "base_mode": 1, "custom_mode": 0, "system_status": 4, "mavlink_version": 3}
    plain = codec.build("HEARTBEAT", fields, sysid=1, compid=1, seq=0, direction=DOWN, link=0, now_s=0.0).raw
    a = codec.sign_injected(plain, signer)
    clock[0] -= 5.0  # wall clock stepped back
    b = codec.sign_injected(plain, signer)
    ts = [int.from_bytes(x[-12:-6], "little") for x in (a, b)]
    assert ts == [1_000_000, 1_000_001] and a[-13] == b[-13] == 7
    assert len(read_strict(a + b)) == 2

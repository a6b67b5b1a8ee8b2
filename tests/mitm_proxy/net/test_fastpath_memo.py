"""The fast route's rewrite memory (mitm_proxy/net/_fastpath.c: learn, verdict, forget) against codec.encode.

After Python rewrote one frame, the route repeats that rewrite for frames with the same key (the payload less
the time field): what it sends must be exactly what the Python path's re-pack gives for that frame, MAVLink 1
and 2, truncated payloads and all; anything it cannot repeat byte for byte (a frame with another key, a signed
one, a damaged one, one received after the stage's time was up) goes up to Python.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavframe import codec
from tests.support.frames_support import heartbeat, mav, mavlink, pack, repacked, signed_mav, verdict_route

pytestmark = pytest.mark.usefixtures("fast_path")  # skipped where it is not built, a failure under CI

DISTANCE_SENSOR = 132
TIME_SPAN = codec.field_span(DISTANCE_SENSOR, "time_boot_ms")


def route(memo: bool = True) -> Any:
    """A route that wants every DISTANCE_SENSOR and may repeat its rewrites (never drained: no socket)."""
    return verdict_route(frozenset({DISTANCE_SENSOR}), {}, {DISTANCE_SENSOR: TIME_SPAN} if memo else {})


def ds(t_ms: int, cm: int, sid: int = 0, *, v1: bool = False, tail: int = 1, seq: int = 0, quality: int = 0) -> bytes:
    """A DISTANCE_SENSOR frame; ``tail`` 0 zeroes what follows the id (MAVLink 2 then truncates there)."""
    msg = mavlink.MAVLink_distance_sensor_message(t_ms, 10, 4000, cm, 0, sid, tail * 25, tail * 255,
                                                  signal_quality=quality)  # fmt: skip
    m = mav()
    m.seq = seq
    return pack(msg, m, v1=v1)


@given(
    cm=st.integers(0, 65535),
    new_cm=st.integers(0, 65535),
    sid=st.integers(0, 3),
    v1=st.booleans(),
    tail=st.integers(0, 1),
    quality=st.integers(0, 100),
    t_a=st.integers(0, 2**32 - 1),
    t_b=st.integers(0, 2**32 - 1),
    seq=st.integers(0, 255),
)
def test_a_repeated_rewrite_is_what_python_packs(cm: int, new_cm: int, sid: int, v1: bool, tail: int,
                                                 quality: int, t_a: int, t_b: int, seq: int) -> None:  # fmt: skip
    r = route()
    a = ds(t_a, cm, sid, v1=v1, tail=tail, quality=quality)
    out_a = repacked(a, current_distance=new_cm)
    assert r.learn(a, out_a, 10.0, True) is True
    b = ds(t_b, cm, sid, v1=v1, tail=tail, quality=quality, seq=seq)  # the same key, another time and number
    assert r.verdict(b, 5.0) == (repacked(b, current_distance=new_cm), 1)
    other = ds(t_b, cm ^ 1, sid, v1=v1, tail=tail, quality=quality)  # another key: Python's to decide
    assert r.verdict(other, 5.0) is None


def test_a_frame_left_as_it_came_is_repeated_as_it_came() -> None:
    r = route()
    a = ds(1000, 250)
    assert r.learn(a, a, 10.0, False) is True
    b = ds(2000, 250, seq=7)
    assert r.verdict(b, 1.0) == (b, 0)


def test_the_memory_holds_until_the_stage_said_and_not_after_a_forget() -> None:
    r = route()
    a = ds(1000, 250)
    r.learn(a, repacked(a, current_distance=300), 10.0, True)
    b = ds(2000, 250)
    assert r.verdict(b, 9.999) is not None
    assert r.verdict(b, 10.0) is None  # received when the time was up: Python decides again
    r.forget()
    assert r.verdict(b, 1.0) is None


def test_only_memo_ids_are_learnt_and_only_whole_unsigned_frames() -> None:
    plain = route(memo=False)
    a = ds(1000, 250)
    assert plain.learn(a, repacked(a, current_distance=300), 10.0, True) is False
    assert plain.verdict(ds(2000, 250), 1.0) is None
    r = route()
    assert r.learn(a + a, a + a, 10.0, False) is False  # not one frame
    assert r.learn(a[:-1], a[:-1], 10.0, False) is False
    s = pack(mavlink.MAVLink_distance_sensor_message(1000, 10, 4000, 250, 0, 0, 25, 255), signed_mav())
    assert r.learn(s, s, 10.0, False) is False


def test_signed_and_damaged_frames_with_a_known_key_go_up() -> None:
    r = route()
    a = ds(1000, 250)
    r.learn(a, repacked(a, current_distance=300), 10.0, True)
    s = pack(mavlink.MAVLink_distance_sensor_message(2000, 10, 4000, 250, 0, 0, 25, 255), signed_mav())
    assert r.verdict(s, 1.0) is None
    b = bytearray(ds(2000, 250))
    b[-1] ^= 0xFF  # a bad CRC: Python counts it
    assert r.verdict(bytes(b), 1.0) is None


def test_a_rewrite_inside_a_datagram_keeps_the_frames_around_it() -> None:
    r = route()
    a = ds(1000, 250, tail=0)  # truncated: the rewrite changes the frame's length
    r.learn(a, repacked(a, current_distance=0), 10.0, True)
    hb = pack(heartbeat(), mav())
    b = ds(3000, 250, tail=0)
    sent = r.verdict(hb + b + hb, 1.0)
    assert sent == (hb + repacked(b, current_distance=0) + hb, 1)
    assert len(repacked(b, current_distance=0)) < len(b)


def test_a_rewrite_of_more_bytes_than_the_route_keeps_is_not_learnt() -> None:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    r = route()
    a = ds(1000, 250, quality=0)
    quaternion = [1.1, -2.3, 3.7, 7.9]  # 16 changed bytes, the fovs 8 more, the time 4, ...
    out = repacked(a, quaternion=quaternion, horizontal_fov=0.3, vertical_fov=0.7, current_distance=1,
                         signal_quality=99, max_distance=1, min_distance=2, covariance=3,
                         time_boot_ms=0x12345678)  # fmt: skip
    changed = sum(x != y for x, y in zip(a[10:-2].ljust(255, b"\0"), out[10:-2].ljust(255, b"\0"), strict=True))
    assert changed > _fastpath.MEMO_PATCH
    assert r.learn(a, out, 10.0, True) is False

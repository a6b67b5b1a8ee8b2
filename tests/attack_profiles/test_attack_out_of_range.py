"""A reading the sensor flags as none stays none; an attacked reading stays inside the sensor's range
(issue 27, item 4: ArduPilot on the ground sends 0 cm under min_distance 20, and +5 m made it 5 m)."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from attack_profiles import Direction, Engine, parse_profile
from secuav_common.loading import InputError
from tests.support.attack_helpers import DISTANCE_SENSOR, GPS_RAW_INT, make_profile, rule, send, started

RANGEFINDER = 173
FAST = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def ds(cm: int, lo: int = 20, hi: int = 4000, quality: int = 0, sid: int = 0, orientation: int = 25) -> dict[str, Any]:
    return {"time_boot_ms": 0, "min_distance": lo, "max_distance": hi, "current_distance": cm, "type": 4,
            "id": sid, "orientation": orientation, "covariance": 0, "horizontal_fov": 0.0, "vertical_fov": 0.0,
            "quaternion": [0.0] * 4, "signal_quality": quality}  # fmt: skip


def out_cm(engine: Engine, fields: dict[str, Any]) -> int:
    action = send(engine, 0.0, fields, msgid=DISTANCE_SENSOR)
    return int((action.fields or {}).get("current_distance", fields["current_distance"]))


def test_ardupilot_on_the_ground_stays_no_reading() -> None:
    engine = started(make_profile(rule("bias", offset=5.0)))
    assert out_cm(engine, ds(0)) == 0  # below min_distance: no target
    assert out_cm(engine, ds(4500)) == 4500  # above max_distance
    assert out_cm(engine, ds(300, quality=1)) == 300  # signal_quality 1: invalid
    assert out_cm(engine, ds(300)) == 800  # a reading: attacked


def test_out_of_range_attack_opts_in() -> None:
    engine = started(make_profile(rule("bias", offset=5.0, out_of_range="attack")))
    assert out_cm(engine, ds(0)) == 500
    assert out_cm(engine, ds(3900)) == 4400  # and may leave the sensor's range


def test_attacked_reading_is_clamped_to_the_sensor_range_and_reported() -> None:
    engine = started(make_profile(rule("bias", offset=5.0)))
    action = send(engine, 0.0, ds(3800), msgid=DISTANCE_SENSOR)
    assert action.fields == {"current_distance": 4000} and action.clamped == ("current_distance",)
    low = send(started(make_profile(rule("bias", offset=-5.0))), 0.0, ds(300), msgid=DISTANCE_SENSOR)
    assert low.fields == {"current_distance": 20} and low.clamped == ("current_distance",)


def test_set_writes_what_the_profile_says_and_garbage_ignores_limits() -> None:
    assert out_cm(started(make_profile(rule("set", value=0.0))), ds(300)) == 0  # "reads 0", as written
    assert out_cm(started(make_profile(rule("set", value=1.0))), ds(0)) == 0  # but no reading stays none
    garbage = started(make_profile(rule("garbage")))
    assert any(out_cm(garbage, ds(0)) != 0 for _ in range(5))  # a sensor gone mad: whatever it had


def test_freeze_remembers_readings_only() -> None:
    engine = started(make_profile(rule("freeze", start_s=1.0)))
    send(engine, 0.0, ds(300), msgid=DISTANCE_SENSOR)
    send(engine, 0.5, ds(0), msgid=DISTANCE_SENSOR)  # no reading: not the value to hold
    action = send(engine, 1.0, ds(900), msgid=DISTANCE_SENSOR)
    assert action.fields == {"current_distance": 300}


def test_rangefinder_follows_its_primary_sensor_limits() -> None:
    engine = started(make_profile({"target": {"quantity": "rangefinder", "sensor_id": 0}, "kind": "bias", "offset": 5}))
    rf = {"distance": 0.0, "voltage": 0.0}
    assert send(engine, 0.0, rf, msgid=RANGEFINDER).untouched  # nothing seen yet: 0 m is no reading
    send(engine, 0.0, ds(0), msgid=DISTANCE_SENSOR)
    assert send(engine, 0.0, {"distance": 0.1, "voltage": 0.0}, msgid=RANGEFINDER).untouched  # under 0.2 m
    action = send(engine, 0.0, {"distance": 38.0, "voltage": 0.0}, msgid=RANGEFINDER)
    assert action.fields == {"distance": 40.0} and action.clamped == ("distance",)
    send(engine, 0.0, ds(300, quality=1), msgid=DISTANCE_SENSOR)  # the primary flags invalid
    assert send(engine, 0.0, {"distance": 3.0, "voltage": 0.0}, msgid=RANGEFINDER).untouched


def test_gps_without_fix_is_no_reading() -> None:
    engine = started(make_profile(rule("bias", sensor_id=None, message="GPS_RAW_INT", target_field="alt", offset=5)))
    gps = {"time_usec": 0, "fix_type": 1, "lat": 0, "lon": 0, "alt": 0, "alt_ellipsoid": 0}
    assert send(engine, 0.0, gps, msgid=GPS_RAW_INT).untouched
    assert send(engine, 0.0, {**gps, "fix_type": 3, "alt": 100}, msgid=GPS_RAW_INT).fields == {"alt": 5100}


def test_out_of_range_spelling_is_checked() -> None:
    with pytest.raises(InputError, match=r"rules\[0\]\.out_of_range.*'drop'"):
        parse_profile({"name": "p", "rules": [rule("bias", offset=1.0, out_of_range="drop")]}, "p.yaml")


@FAST
@given(
    cm=st.integers(0, 65535),
    lo=st.integers(0, 65535),
    hi=st.integers(0, 65535),
    quality=st.integers(0, 100),
    offset=st.floats(-700.0, 700.0, allow_nan=False),
    kind=st.sampled_from(["bias", "ramp", "scale", "noise", "sinusoid"]),
)
def test_no_reading_never_becomes_one_and_readings_stay_in_range(
    cm: int, lo: int, hi: int, quality: int, offset: float, kind: str
) -> None:
    params = {"bias": {"offset": offset}, "ramp": {"rate_per_s": offset, "offset": offset},
              "scale": {"factor": offset}, "noise": {"std": abs(offset) + 0.1},
              "sinusoid": {"amplitude": offset, "period_s": 1.0}}[kind]  # fmt: skip
    engine = Engine(make_profile(rule(kind, **params)))
    engine.activate(0.0)
    fields = ds(cm, lo, hi, quality)
    action = engine.process(0.7, DISTANCE_SENSOR, fields, Direction.DOWNLINK, 1, 1)
    got = (action.fields or {}).get("current_distance", cm)
    if not lo <= cm <= hi or quality == 1:
        assert action.untouched and got == cm
    else:
        assert lo <= got <= hi  # clamped to the sensor's range, never past it into "no reading"

"""Targets by quantity: validation, the carrier mapping, ArduPilot's primary rangefinder, the warnings."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from attack_profiles import library, parse_profile
from attack_profiles.quantities import CARRIERS, M_PER_DEG, NOT_COVERED, mapping_table
from attack_profiles.true_copy import true_copies
from attack_profiles.units import MESSAGES
from secuav_common.loading import InputError
from tests.support.attack_helpers import (
    DISTANCE_SENSOR,
    GLOBAL_POSITION_INT,
    LOCAL_POSITION_NED,
    make_profile,
    rule,
    send,
    started,
)

RANGEFINDER = 173
FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def q(quantity: str, kind: str = "bias", field: str | None = None, **kw: Any) -> dict[str, Any]:
    target: dict[str, Any] = {"quantity": quantity}
    if field is not None:
        target["field"] = field
    for key in ("sensor_id", "sysid"):
        if key in kw:
            target[key] = kw.pop(key)
    return {"target": target, "kind": kind, **kw}


def ds(cm: int, sid: int = 0, orientation: int = 25) -> dict[str, Any]:
    return {"time_boot_ms": 0, "min_distance": 20, "max_distance": 4000, "current_distance": cm, "type": 4,
            "id": sid, "orientation": orientation, "covariance": 0, "horizontal_fov": 0.0, "vertical_fov": 0.0,
            "quaternion": [0.0] * 4, "signal_quality": 0}  # fmt: skip


@pytest.mark.parametrize(
    ("target", "where", "why"),
    [
        ({"message": "DISTANCE_SENSOR", "quantity": "rangefinder"}, r"rules\[0\]\.target", "exactly one"),
        ({}, r"rules\[0\]\.target", "exactly one"),
        ({"quantity": "position"}, r"rules\[0\]\.target\.field", "north, east"),
        ({"quantity": "altitude", "field": "down"}, r"rules\[0\]\.target\.field", "not a component.*'down'"),
        ({"quantity": "altitude", "sensor_id": 0}, r"rules\[0\]\.target\.sensor_id", "no sensor id"),
        ({"quantity": "speed"}, r"rules\[0\]\.target\.quantity", "rangefinder"),
    ],
)
def test_bad_quantity_targets_name_the_field(target: dict[str, Any], where: str, why: str) -> None:
    with pytest.raises(InputError, match=f"{where}.*{why}"):
        parse_profile({"name": "p", "rules": [{"target": target, "kind": "bias", "offset": 1.0}]}, "p.yaml")


def test_set_and_scale_refused_on_datum_quantities() -> None:
    with pytest.raises(InputError, match=r"rules\[0\]\.kind.*datums.*'set'"):
        make_profile(q("altitude", "set", value=10.0))
    make_profile(q("rangefinder", "set", value=1.0))  # one sensor, one datum: fine


def test_carrier_table_names_real_fields() -> None:
    for c in CARRIERS:
        assert c.field in MESSAGES[c.message].fields, c
        assert c.lat_field is None or c.lat_field in MESSAGES[c.message].fields
    table = mapping_table()
    assert "| rangefinder | distance | RANGEFINDER | `distance` |" in table and "OBSTACLE_DISTANCE" in table


def test_rangefinder_rewrites_both_messages_of_the_same_sensor() -> None:
    engine = started(make_profile(q("rangefinder", sensor_id=0, offset=5.0)))
    assert send(engine, 0.0, ds(999), msgid=DISTANCE_SENSOR).fields == {"current_distance": 1499}
    assert send(engine, 0.0, {"distance": 9.99, "voltage": 0.0}, msgid=RANGEFINDER).fields == {"distance": 14.99}
    assert send(engine, 0.0, ds(999, sid=1), msgid=DISTANCE_SENSOR).untouched  # another sensor


def test_rangefinder_message_follows_the_lowest_downward_id() -> None:
    engine = started(make_profile(q("rangefinder", sensor_id=5, offset=1.0)))
    rf = {"distance": 3.0, "voltage": 0.0}
    assert send(engine, 0.0, rf, msgid=RANGEFINDER).untouched  # nothing seen yet: ArduPilot's first instance, 0
    send(engine, 0.0, ds(500, sid=0, orientation=0), msgid=DISTANCE_SENSOR)  # forward: not the primary
    send(engine, 0.0, ds(300, sid=5), msgid=DISTANCE_SENSOR)
    assert send(engine, 0.0, rf, msgid=RANGEFINDER).fields == {"distance": 4.0}
    other = started(make_profile(q("rangefinder", sensor_id=0, offset=1.0)))
    send(other, 0.0, ds(300, sid=5), msgid=DISTANCE_SENSOR)
    assert send(other, 0.0, rf, msgid=RANGEFINDER).untouched


def test_offline_arrays_see_quantity_rules_too() -> None:
    engine = started(make_profile(q("rangefinder", sensor_id=0, offset=2.0)))
    out = engine.apply_array(np.array([0.0, 1.0]), np.array([[3.0, 4.0], [5.0, 6.0]]), [0, 1])
    assert out.tolist() == [[5.0, 4.0], [7.0, 6.0]]


@FAST
@given(
    lat_deg=st.floats(-80.0, 80.0),
    lon_deg=st.floats(-179.0, 179.0),
    north=st.floats(-500.0, 500.0),
    east=st.floats(-500.0, 500.0),
    up=st.floats(-100.0, 100.0),
    x=st.floats(-1e3, 1e3),
    z=st.floats(-1e3, 1e3),
)
def test_position_and_altitude_move_every_carrier_by_the_same_metres(
    lat_deg: float, lon_deg: float, north: float, east: float, up: float, x: float, z: float
) -> None:
    engine = started(make_profile(q("position", field="north", offset=north), q("position", field="east",
                                  offset=east), q("altitude", offset=up)))  # fmt: skip
    gpi = {"time_boot_ms": 0, "lat": round(lat_deg * 1e7), "lon": round(lon_deg * 1e7), "alt": 500_000,
           "relative_alt": 10_000, "vx": 0, "vy": 0, "vz": 0, "hdg": 0}  # fmt: skip
    assume(gpi["lat"] != 0 or gpi["lon"] != 0)  # 0/0 is "no position yet" (test_attack_out_of_range)
    got = gpi | (send(engine, 0.0, gpi, msgid=GLOBAL_POSITION_INT).fields or {})
    assert abs((got["lat"] - gpi["lat"]) * 1e-7 * M_PER_DEG - north) < 0.02  # 1e-7 deg: 1.1 cm
    cos_lat = math.cos(math.radians(gpi["lat"] * 1e-7))
    assert abs((got["lon"] - gpi["lon"]) * 1e-7 * M_PER_DEG * cos_lat - east) < 0.02
    assert abs((got["alt"] - gpi["alt"]) * 1e-3 - up) < 1e-3 and abs((got["relative_alt"] - 10_000) * 1e-3 - up) < 1e-3
    lp = {"time_boot_ms": 0, "x": x, "y": 0.0, "z": z, "vx": 0.0, "vy": 0.0, "vz": 0.0}
    moved = lp | (send(engine, 0.0, lp, msgid=LOCAL_POSITION_NED).fields or {})
    assert math.isclose(moved["x"], x + north, abs_tol=1e-9) and math.isclose(moved["y"], east, abs_tol=1e-9)
    assert math.isclose(moved["z"], z - up, abs_tol=1e-9)  # NED: up is minus z


def test_a_message_target_is_told_about_its_twins() -> None:
    warnings = true_copies(make_profile(rule("bias", offset=5.0)))
    assert len(warnings) == 1 and "RANGEFINDER.distance" in warnings[0] and "quantity: rangefinder" in warnings[0]
    drift = true_copies(library.load("gps-drift"))
    assert len(drift) == 1 and "rules[0, 1, 2] rewrite position north" in drift[0] and "GPS2_RAW.lat" in drift[0]
    assert "GPS_RAW_INT.lat" not in drift[0].split(";")[1]  # rules[2] covers it
    both = make_profile(rule("bias", offset=5.0), rule("bias", sensor_id=None, message="RANGEFINDER", offset=5.0))
    assert true_copies(both) == []  # every carrier covered, each by its own rule


def test_a_quantity_target_is_told_what_is_not_covered() -> None:
    (warning,) = true_copies(make_profile(q("altitude", offset=1.0)))
    assert all(name in warning for name, _ in NOT_COVERED["altitude"])


def test_a_rangefinder_target_is_told_of_what_reveals_px4s_downward_rangefinder() -> None:
    # measured against PX4 SIH (docs/px4.md): ALTITUDE.bottom_clearance stays within cm of the true
    # reading while DISTANCE_SENSOR says +5 m, and altitude_local - altitude_terrain gives it back
    (warning,) = true_copies(make_profile(q("rangefinder", sensor_id=0, offset=5.0)))
    for name in ("ALTITUDE.bottom_clearance", "ALTITUDE.altitude_terrain", "OPTICAL_FLOW_RAD.distance"):
        assert name in warning


def test_validate_prints_the_warnings(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text("name: p\nrules:\n  - {target: {message: DISTANCE_SENSOR, sensor_id: 0}, kind: bias, offset: 5}\n")
    done = subprocess.run([sys.executable, "-m", "attack_profiles", "validate", str(path)], capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0 and done.stdout.startswith("ok: p")
    want = "warning: rules[0] rewrite rangefinder distance in DISTANCE_SENSOR; RANGEFINDER.distance still carries"
    assert want in done.stderr


@FAST
@given(
    quantity=st.sampled_from(["rangefinder", "altitude", "position"]),
    data=st.data(),
    kind=st.sampled_from(["bias", "ramp", "noise", "drop", "delay", "freeze"]),
    keep=st.sampled_from(["keep", "attack"]),
)
def test_quantity_profiles_round_trip_and_build(quantity: str, data: st.DataObject, kind: str, keep: str) -> None:
    field = data.draw(st.sampled_from({"rangefinder": [None, "distance"], "altitude": [None, "up"],
                                       "position": ["north", "east"]}[quantity]))  # fmt: skip
    params = {"bias": {"offset": 1.0}, "ramp": {"rate_per_s": 0.5}, "noise": {"std": 0.3}, "drop": {},
              "delay": {"delay_s": 0.2}, "freeze": {}}[kind]  # fmt: skip
    with_id = quantity == "rangefinder" and data.draw(st.booleans())
    extra = {"sensor_id": data.draw(st.integers(0, 255))} if with_id else {}
    profile = make_profile(q(quantity, kind, field, out_of_range=keep, **extra, **params))
    again = parse_profile(profile.canonical_json(), "again.json")
    assert again == profile and again.content_hash() == profile.content_hash()
    engine = started(profile)
    assert engine.message_ids  # every carrier message, decoded only for these


def test_barometric_height_moves_only_when_the_imu_says_it_is_fresh() -> None:
    engine = started(make_profile(q("altitude", offset=2.0)))
    imu = {"time_usec": 0, "pressure_alt": 488.0, "fields_updated": 0x800}
    assert send(engine, 0.0, imu, msgid=105).fields == {"pressure_alt": 490.0}
    assert send(engine, 0.0, {**imu, "fields_updated": 0x1FF}, msgid=105).untouched  # not updated: not a reading


def test_a_rule_on_a_rangefinder_other_than_id_0_says_when_ardupilots_twin_still_carries_it() -> None:
    picked = make_profile({"target": {"message": "DISTANCE_SENSOR", "sensor_id": 2}, "kind": "bias", "offset": 5})
    (warning,) = true_copies(picked)
    assert "RANGEFINDER.distance (if sensor 2 is the vehicle's lowest-id downward rangefinder)" in warning
    (warning,) = true_copies(
        make_profile({"target": {"message": "DISTANCE_SENSOR", "sensor_id": [0, 2]}, "kind": "bias", "offset": 5})
    )
    assert "RANGEFINDER.distance still carries the true value" in warning  # id 0 is the primary by default

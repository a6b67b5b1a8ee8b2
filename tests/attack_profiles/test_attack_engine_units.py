"""Unit conversion both ways, clamping, composition order, matching and the vehicle clock."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import FORWARD, Direction, Engine
from attack_profiles.units import MESSAGES
from tests.support.attack_helpers import (
    GLOBAL_POSITION_INT,
    GPS_RAW_INT,
    LOCAL_POSITION_NED,
    attacked_cm,
    distance,
    make_profile,
    rule,
    send,
    started,
)


@pytest.mark.parametrize("message", sorted(MESSAGES))
def test_unit_tables_agree_with_pymavlink(message: str) -> None:
    spec = MESSAGES[message]
    cls = mavlink.mavlink_map[spec.msgid]
    assert cls.msgname == message
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    for name, field in spec.fields.items():
        assert types[name] == field.wire_type, name
        if field.wire_unit:
            assert cls.fieldunits_by_name.get(name) == field.wire_unit, name
    for extra in (spec.id_field, spec.time_field):
        assert extra is None or extra in types


def _gpi(**over: int) -> dict[str, int]:
    fields = {"time_boot_ms": 0, "lat": 473977420, "lon": 85455940, "alt": 488000, "relative_alt": 2500}
    fields.update({"vx": 0, "vy": 0, "vz": 0, "hdg": 9000})
    fields.update(over)
    return fields


def test_global_position_degrees_and_millimetres_convert_both_ways() -> None:
    profile = make_profile(
        rule("bias", sensor_id=None, message="GLOBAL_POSITION_INT", target_field="lat", offset=1e-5),
        rule("bias", sensor_id=None, message="GLOBAL_POSITION_INT", target_field="alt", offset=-0.25),
        rule("bias", sensor_id=None, message="GLOBAL_POSITION_INT", target_field="vx", offset=1.5),
        rule("set", sensor_id=None, message="GLOBAL_POSITION_INT", target_field="hdg", value=180.0),
    )
    action = send(started(profile), 0.0, _gpi(), msgid=GLOBAL_POSITION_INT)
    assert action.fields == {"lat": 473977520, "alt": 487750, "vx": 150, "hdg": 18000}
    assert action.clamped == ()


def test_local_position_is_metres_on_the_wire() -> None:
    profile = make_profile(rule("scale", sensor_id=None, message="LOCAL_POSITION_NED", target_field="z", factor=2.0))
    pos = {"time_boot_ms": 0, "x": 1.0, "y": 2.0, "z": -2.5, "vx": 0.0, "vy": 0.0, "vz": 0.0}
    assert send(started(profile), 0.0, pos, msgid=LOCAL_POSITION_NED).fields == {"z": -5.0}


def test_clamping_to_the_wire_range_is_reported() -> None:
    # out_of_range: attack lifts the sensor's own [min, max], so only the wire type bounds the value.
    free = {"out_of_range": "attack"}
    engine = started(make_profile(rule("bias", offset=-5.0, **free), rule("bias", sensor_id=1, offset=700.0, **free)))
    low = send(engine, 0.0, distance(0, 250))
    assert low.fields == {"current_distance": 0} and low.clamped == ("current_distance",)
    high = send(engine, 0.0, distance(1, 250))
    assert high.fields == {"current_distance": 65535} and high.clamped == ("current_distance",)
    vx = make_profile(rule("bias", sensor_id=None, message="GLOBAL_POSITION_INT", target_field="vx", offset=400.0))
    action = send(started(vx), 0.0, _gpi(vx=100), msgid=GLOBAL_POSITION_INT)
    assert action.fields == {"vx": 32767} and action.clamped == ("vx",)


def test_clamped_fields_pack_into_a_real_frame() -> None:
    engine = started(make_profile(rule("bias", offset=1000.0, out_of_range="attack")))
    fields = distance(0, 250)
    action = send(engine, 0.0, fields)
    fields.update(action.fields or {})
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mavlink.MAVLink_distance_sensor_message(**fields)
    frame = msg.pack(mav)
    decoded = mav.parse_char(frame)
    assert decoded.current_distance == 65535


def test_apply_array_clamps_to_the_physical_range() -> None:
    engine = started(make_profile(rule("bias", offset=-3.0)))
    out = engine.apply_array(np.array([0.0]), np.array([[2.0]]), [0])
    assert out[0, 0] == 0.0


def test_rules_compose_in_order() -> None:
    bias_then_scale = make_profile(rule("bias", offset=1.0), rule("scale", factor=2.0))
    scale_then_bias = make_profile(rule("scale", factor=2.0), rule("bias", offset=1.0))
    assert attacked_cm(started(bias_then_scale), 0.0, 0, 100) == 400
    assert attacked_cm(started(scale_then_bias), 0.0, 0, 100) == 300
    action = send(started(bias_then_scale), 0.0, distance(0, 100))
    assert action.rules == (0, 1)


def test_a_drop_ends_the_chain() -> None:
    engine = started(make_profile(rule("bias", offset=1.0), rule("drop"), rule("set", value=9.0)))
    action = send(engine, 0.0, distance(0, 100))
    assert action.drop and action.rules == (0, 1)


def test_freeze_after_bias_holds_the_biased_value() -> None:
    engine = started(make_profile(rule("bias", offset=1.0), rule("freeze", start_s=1.0)))
    attacked_cm(engine, 0.5, 0, 100)
    assert attacked_cm(engine, 1.5, 0, 300) == 200


def test_fields_of_one_message_are_attacked_independently() -> None:
    profile = make_profile(
        rule("bias", sensor_id=None, message="LOCAL_POSITION_NED", target_field="x", offset=1.0),
        rule("bias", sensor_id=None, message="LOCAL_POSITION_NED", target_field="y", offset=-1.0),
        rule("scale", sensor_id=None, message="LOCAL_POSITION_NED", target_field="x", factor=3.0),
    )
    pos = {"time_boot_ms": 0, "x": 1.0, "y": 1.0, "z": 0.0, "vx": 0.0, "vy": 0.0, "vz": 0.0}
    assert send(started(profile), 0.0, pos, msgid=LOCAL_POSITION_NED).fields == {"x": 6.0, "y": 0.0}


def test_direction_and_sysid_filters() -> None:
    profile = make_profile(
        rule("bias", offset=1.0, target_sysid=2),
        rule("bias", sensor_id=1, offset=1.0, target_direction="uplink"),
        rule("bias", sensor_id=2, offset=1.0, target_direction="both"),
    )
    engine = started(profile)
    assert send(engine, 0.0, distance(0, 100), sysid=1) == FORWARD
    assert send(engine, 0.0, distance(0, 100), sysid=2).fields == {"current_distance": 200}
    assert send(engine, 0.0, distance(1, 100)) == FORWARD
    assert send(engine, 0.0, distance(1, 100), direction=Direction.UPLINK).fields == {"current_distance": 200}
    for direction in Direction:
        assert send(engine, 0.0, distance(2, 100), direction=direction).fields == {"current_distance": 200}


def test_sensor_id_range_and_untargeted_messages() -> None:
    engine = started(make_profile(rule("bias", sensor_id={"first": 11, "last": 13}, offset=1.0)))
    assert engine.message_ids == frozenset({132})
    assert [attacked_cm(engine, 0.0, sid, 100) for sid in (10, 11, 12, 13, 14)] == [100, 200, 200, 200, 100]
    assert send(engine, 0.0, {"lat": 1}, msgid=GLOBAL_POSITION_INT) is FORWARD


def test_activation_clock_starts_at_activate_or_first_message() -> None:
    profile = make_profile(rule("bias", offset=1.0, start_s=5.0))
    engine = Engine(profile)
    assert attacked_cm(engine, 100.0, 0, 100) == 100  # first call activates at 100 s
    assert attacked_cm(engine, 105.0, 0, 100) == 200
    engine.activate(200.0)
    assert attacked_cm(engine, 204.0, 0, 100) == 100


def test_vehicle_clock_uses_time_boot_ms_not_the_callers_clock() -> None:
    engine = started(make_profile(rule("bias", offset=1.0, start_s=10.0, end_s=20.0), clock="vehicle"))
    assert send(engine, 50.0, distance(0, 100, time_boot_ms=9_999)) == FORWARD
    assert send(engine, 0.0, distance(0, 100, time_boot_ms=10_000)).fields == {"current_distance": 200}
    assert send(engine, 0.0, distance(0, 100, time_boot_ms=20_000)) == FORWARD


def test_vehicle_clock_reads_time_usec_and_falls_back_for_unix_time() -> None:
    profile = make_profile(
        rule("bias", sensor_id=None, message="GPS_RAW_INT", target_field="alt", offset=1.0, start_s=10.0),
        clock="vehicle",
    )
    engine = started(profile)
    gps = {"time_usec": 12_000_000, "lat": 0, "lon": 0, "alt": 1000}
    assert send(engine, 0.0, gps, msgid=GPS_RAW_INT).fields == {"alt": 2000}
    # A UNIX-epoch time_usec says nothing about boot time: use this vehicle's last boot time,
    # which per vehicle is 12 s for sysid 1 and unknown for sysid 2.
    epoch = {**gps, "time_usec": 1_700_000_000_000_000}
    assert send(engine, 0.0, epoch, msgid=GPS_RAW_INT).fields == {"alt": 2000}
    assert send(engine, 0.0, epoch, msgid=GPS_RAW_INT, sysid=2) == FORWARD


def test_missing_field_in_message_is_left_alone() -> None:
    engine = started(make_profile(rule("bias", offset=1.0)))
    assert send(engine, 0.0, {"id": 0, "time_boot_ms": 0}) == FORWARD

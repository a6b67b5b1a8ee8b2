"""Any message, any field: specs derived from the dialect, arrays by index, exact round trips, one-line errors."""

from __future__ import annotations

import struct
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import Direction, parse_profile
from attack_profiles import dialect as derived
from attack_profiles.units import MESSAGES, FieldSpec
from secuav_common.loading import InputError
from tests.support.attack_helpers import distance, make_profile, rule, send, started

ALL_MESSAGES = sorted(cls.msgname for cls in mavlink.mavlink_map.values())
TYPED = [
    "DISTANCE_SENSOR", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "ODOMETRY", "ATTITUDE",
    "RANGEFINDER", "VFR_HUD", "ALTITUDE", "GPS2_RAW", "TERRAIN_REPORT", "AHRS2", "AHRS3", "HIGHRES_IMU", "SIMSTATE",
]  # fmt: skip
OBSTACLE_DISTANCE = mavlink.MAVLINK_MSG_ID_OBSTACLE_DISTANCE
COMMAND_LONG = mavlink.MAVLINK_MSG_ID_COMMAND_LONG


def _all_fields() -> list[FieldSpec]:
    return [spec for name in ALL_MESSAGES for spec in derived.fields(name).values()]


def test_iterating_messages_still_lists_the_typed_fifteen_only() -> None:
    assert list(MESSAGES) == TYPED


def test_importing_the_library_does_not_import_the_dialect() -> None:
    code = "import sys, attack_profiles; sys.exit('pymavlink' in ' '.join(sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


@pytest.mark.parametrize("name", ALL_MESSAGES)
def test_every_message_of_the_dialect_is_a_target_with_the_xmls_types_and_units(name: str) -> None:
    spec = MESSAGES[name]
    cls = mavlink.mavlink_map[spec.msgid]
    assert cls.msgname == name
    for i, (field, wire_type) in enumerate(zip(cls.fieldnames, cls.fieldtypes, strict=True)):
        length = cls.array_lengths[cls.orders[i]]
        if wire_type == "char":
            assert derived.char_fields(name)[field] == length
            continue
        names = [f"{field}[{k}]" for k in range(length)] if length else [field]
        for element in names:
            assert spec.field(element) is not None, element  # the typed table's, where it has the field
            got = derived.fields(name).get(element)
            assert got is not None, element
            assert got.wire_type == wire_type.removesuffix("_mavlink_version"), element
            assert got.wire_unit == cls.fieldunits_by_name.get(field, "")
            assert got.enum == cls.fieldenums_by_name.get(field)
        assert spec.field(f"{field}[{length}]") is None


def test_typed_fields_keep_their_table_and_other_fields_come_from_the_dialect() -> None:
    ds = MESSAGES["DISTANCE_SENSOR"]
    assert ds.field("current_distance") is ds.fields["current_distance"]
    assert ds.field("covariance").wire_unit == ""  # type: ignore[union-attr]  # the typed table's choice
    orientation = ds.field("orientation")
    assert orientation is not None and orientation.enum == "MAV_SENSOR_ORIENTATION"
    assert ds.field("quaternion[3]") is not None and "quaternion[3]" not in ds.fields


def test_units_convert_as_the_xml_says() -> None:
    lat = MESSAGES["SET_POSITION_TARGET_GLOBAL_INT"].field("lat_int")
    assert lat is not None and (lat.unit, lat.scale) == ("deg", 1e-7)
    temp = MESSAGES["SCALED_PRESSURE"].field("temperature")
    assert temp is not None and (temp.unit, temp.scale) == ("degC", 0.01)
    usec = MESSAGES["GPS_INPUT"].field("time_usec")
    assert usec is not None and (usec.unit, usec.scale) == ("us", 1)  # 64-bit integers are never scaled
    param7 = MESSAGES["COMMAND_LONG"].field("param7")
    assert param7 is not None and (param7.unit, param7.scale, param7.integer) == ("", 1.0, False)


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_integer_fields_round_trip_exactly(data: st.DataObject) -> None:
    spec = data.draw(st.sampled_from([s for s in _all_fields() if s.integer]))
    wire = data.draw(st.integers(int(spec.lo), int(spec.hi)))
    assert spec.to_wire(spec.to_physical(wire)) == (wire, False)


_F32 = struct.Struct("<f")


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_float_fields_round_trip_to_the_same_float32(data: st.DataObject) -> None:
    spec = data.draw(st.sampled_from([s for s in [*_all_fields(), *MESSAGES["ATTITUDE"].fields.values()]
                                      if s.wire_type == "float"]))  # fmt: skip
    wire = data.draw(st.floats(width=32, allow_nan=False, allow_infinity=False))
    back, clamped = spec.to_wire(spec.to_physical(wire))
    assert not clamped
    assert _F32.pack(back) == _F32.pack(wire)


def test_an_array_element_is_rewritten_in_place() -> None:
    profile = make_profile(rule("bias", sensor_id=None, message="OBSTACLE_DISTANCE", target_field="distances[3]",
                                offset=1.5))  # fmt: skip
    distances = list(range(100, 172))
    fields = {"time_usec": 0, "sensor_type": 0, "distances": distances, "increment": 5, "min_distance": 10,
              "max_distance": 4000, "increment_f": 0.0, "angle_offset": 0.0, "frame": 12}  # fmt: skip
    action = send(started(profile), 0.0, fields, msgid=OBSTACLE_DISTANCE)
    assert action.fields == {"distances": [*distances[:3], 103 + 150, *distances[4:]]}
    assert fields["distances"] == distances  # the frame's own list is left as it came


def test_an_extra_field_of_a_typed_message_is_a_target_too() -> None:
    profile = make_profile(rule("set", message="DISTANCE_SENSOR", target_field="orientation", value=25))
    action = send(started(profile), 0.0, distance(0, 250))
    assert action.fields == {"orientation": 25}


def test_a_command_field_is_rewritten_in_its_own_units() -> None:
    profile = make_profile(rule("bias", sensor_id=None, message="COMMAND_LONG", target_field="param7", offset=7.0,
                                target_direction="uplink"))  # fmt: skip
    fields = {"target_system": 1, "target_component": 1, "command": 22, "confirmation": 0, "param1": 0.0,
              "param2": 0.0, "param3": 0.0, "param4": 0.0, "param5": 0.0, "param6": 0.0, "param7": 5.0}  # fmt: skip
    engine = started(profile)
    assert send(engine, 0.0, fields, msgid=COMMAND_LONG, direction=Direction.UPLINK).fields == {"param7": 12.0}
    assert send(engine, 0.0, fields, msgid=COMMAND_LONG).untouched  # downlink: not this rule's


BAD = [
    ({"message": "COMAND_LONG", "field": "param7"}, "rules[0].target.message", "closest: COMMAND_LONG"),
    ({"message": "COMMAND_LONG", "field": "parm7"}, "rules[0].target.field", "closest: param7"),
    ({"message": "OBSTACLE_DISTANCE", "field": "distances"}, "rules[0].target.field", "distances[0] to distances[71]"),
    ({"message": "OBSTACLE_DISTANCE", "field": "distances[72]"}, "rules[0].target.field", "has 72 elements"),
    ({"message": "PARAM_SET", "field": "param_id"}, "rules[0].target.field", "is text"),
]


@pytest.mark.parametrize(("target", "path", "says"), BAD)
def test_a_wrong_message_or_field_is_one_line_naming_the_closest(target: dict, path: str, says: str) -> None:
    with pytest.raises(InputError) as info:
        parse_profile({"name": "t", "rules": [{"target": target, "kind": "bias", "offset": 1}]}, "p.yaml")
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"p.yaml: {path}: ") and says in text, text


def test_a_set_outside_a_derived_fields_wire_range_is_refused_when_read() -> None:
    doc = {"name": "t", "rules": [{"target": {"message": "COMMAND_LONG", "field": "command"}, "kind": "set",
                                   "value": 70000}]}  # fmt: skip
    with pytest.raises(InputError, match=r"^p\.yaml: rules\[0\]\.value: COMMAND_LONG\.command \(uint16_t\) carries "
                       r"0 to 65535 \(got 70000\.0\)$"):  # fmt: skip
        parse_profile(doc, "p.yaml")
    gps = {"target": {"message": "GPS_INPUT", "field": "lat"}, "kind": "set", "value": 215.0}
    with pytest.raises(InputError, match=r"rules\[0\]\.value: GPS_INPUT\.lat \(int32_t\) carries -214\.748 to "):
        parse_profile({"name": "t", "rules": [gps]}, "p.yaml")
    parse_profile({"name": "t", "rules": [{**gps, "value": 47.5}]}, "p.yaml")


def test_garbage_over_a_whole_dialect_message_keeps_its_clock_and_packs() -> None:
    from mavframe import codec
    from mavframe.packet import Packet

    profile = make_profile({"target": {"message": "OBSTACLE_DISTANCE"}, "kind": "garbage", "scope": "frame"})
    cls = codec.BY_NAME["OBSTACLE_DISTANCE"]
    fields = {n: 0 for n in cls.fieldnames} | {"time_usec": 123456, "distances": [100] * 72}
    pkt = codec.build("OBSTACLE_DISTANCE", fields, sysid=1, compid=1, seq=0, direction=Direction.DOWNLINK, link=0,
                      now_s=0.0)  # fmt: skip
    decoded = codec.decode(Packet(pkt.raw, pkt.header, Direction.DOWNLINK, 0, 0.0))
    action = send(started(profile), 0.0, decoded, msgid=OBSTACLE_DISTANCE)
    assert action.fields is not None and "time_usec" not in action.fields
    assert len(action.fields["distances"]) == 72 and action.fields["distances"] != [100] * 72
    decoded.update(action.fields)
    again = Packet(pkt.raw, pkt.header, Direction.DOWNLINK, 0, 0.0, fields=decoded, changed=True)
    (msg,) = mavlink.MAVLink(None).parse_buffer(codec.encode(again)) or []
    assert msg.time_usec == 123456 and list(msg.distances) == action.fields["distances"]

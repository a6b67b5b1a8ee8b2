"""Rules toward the vehicle on commands, parameters and setpoints, picked out by ``where`` (issue 33 item 4)."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import Action, Direction, Engine, library, parse_profile
from mavframe import codec
from mavframe.packet import Packet
from secuav_common.loading import InputError
from tests.support.attack_helpers import make_profile, started

UP = Direction.UPLINK
TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
REPOSITION = mavlink.MAV_CMD_DO_REPOSITION
RTL = mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH


def up(message: str, field: str | None = None, where: dict[str, Any] | None = None, **target: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"message": message, "direction": "uplink", **target}
    if field is not None:
        out["field"] = field
    if where is not None:
        out["where"] = where
    return out


def decoded(message: str, **fields: Any) -> tuple[int, dict[str, Any]]:
    """(msgid, fields) as the proxy's codec decodes a frame built with these fields (zeros elsewhere)."""
    cls = codec.BY_NAME[message]
    zeros = {n: ("" if t == "char" else 0) for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)}
    for n, length in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
        if length and cls.fieldtypes[cls.fieldnames.index(n)] != "char":
            zeros[n] = [0] * length
    pkt = codec.build(message, {**zeros, **fields}, sysid=255, compid=190, seq=0, direction=UP, link=0, now_s=0.0)
    return pkt.header.msgid, codec.decode(Packet(pkt.raw, pkt.header, UP, 0, 0.0))


def command_long(command: int, **params: float) -> tuple[int, dict[str, Any]]:
    return decoded("COMMAND_LONG", target_system=1, target_component=1, command=command, **params)


def run(engine: Engine, frame: tuple[int, dict[str, Any]], direction: Direction = UP) -> Action:
    msgid, fields = frame
    return engine.process(0.0, msgid, fields, direction, 255, 190)


def test_takeoff_altitude_is_rewritten_and_other_commands_pass() -> None:
    engine = started(make_profile({"target": up("COMMAND_LONG", "param7", {"command": "MAV_CMD_NAV_TAKEOFF"}),
                                   "kind": "set", "value": 12.0}))  # fmt: skip
    assert run(engine, command_long(TAKEOFF, param7=5.0)).fields == {"param7": 12.0}
    assert run(engine, command_long(ARM, param1=1.0, param7=5.0)).untouched
    assert run(engine, command_long(TAKEOFF, param7=5.0), Direction.DOWNLINK).untouched


def test_enum_names_without_prefix_lists_and_numbers_all_match() -> None:
    for where in ({"command": "NAV_TAKEOFF"}, {"command": [ARM, "NAV_TAKEOFF"]}, {"command": TAKEOFF}):
        engine = started(make_profile({"target": up("COMMAND_LONG", "param7", where), "kind": "bias", "offset": 1}))
        assert run(engine, command_long(TAKEOFF, param7=5.0)).fields == {"param7": 6.0}, where


def test_reposition_target_in_command_long_and_command_int() -> None:
    where = {"command": "MAV_CMD_DO_REPOSITION"}
    profile = make_profile(
        {"target": up("COMMAND_LONG", "param5", where), "kind": "bias", "offset": 0.001},
        {"target": up("COMMAND_LONG", "param7", where), "kind": "bias", "offset": 20.0},
        # COMMAND_INT x/y carry no unit in the XML: wire integers, 1e7 degrees in a global frame.
        {"target": up("COMMAND_INT", "x", {**where, "frame": "MAV_FRAME_GLOBAL_RELATIVE_ALT_INT"}), "kind": "bias",
         "offset": 10000},
        {"target": up("COMMAND_INT", "y", where), "kind": "set", "value": 85000000},
    )  # fmt: skip
    engine = started(profile)
    long = run(engine, command_long(REPOSITION, param5=47.3977, param6=8.5456, param7=30.0))
    assert long.fields is not None and set(long.fields) == {"param5", "param7"}
    assert long.fields["param5"] == pytest.approx(47.3987) and long.fields["param7"] == 50.0
    frame = decoded("COMMAND_INT", command=REPOSITION, frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                    x=473977000, y=85456000, z=30.0)  # fmt: skip
    assert run(engine, frame).fields == {"x": 473987000, "y": 85000000}
    local = decoded("COMMAND_INT", command=REPOSITION, frame=mavlink.MAV_FRAME_LOCAL_NED, x=10000, y=20000)
    assert run(engine, local).fields == {"y": 85000000}  # x's rule matches global frames only


def test_param_set_value_matched_on_its_name() -> None:
    engine = started(make_profile({"target": up("PARAM_SET", "param_value", {"param_id": "RTL_ALT"}), "kind": "set",
                                   "value": 300.0}))  # fmt: skip
    rtl = decoded("PARAM_SET", target_system=1, target_component=1, param_id="RTL_ALT", param_value=1500.0,
                  param_type=mavlink.MAV_PARAM_TYPE_REAL32)  # fmt: skip
    other = decoded("PARAM_SET", target_system=1, target_component=1, param_id="RTL_ALT_FINAL", param_value=0.0,
                    param_type=mavlink.MAV_PARAM_TYPE_REAL32)  # fmt: skip
    assert run(engine, rtl).fields == {"param_value": 300.0}
    assert run(engine, other).untouched


def test_setpoints_local_and_global() -> None:
    profile = make_profile(
        {"target": up("SET_POSITION_TARGET_LOCAL_NED", "z"), "kind": "bias", "offset": -3.0},
        {"target": up("SET_POSITION_TARGET_GLOBAL_INT", "lat_int"), "kind": "bias", "offset": 1e-4},
        {"target": up("SET_POSITION_TARGET_GLOBAL_INT", "alt"), "kind": "scale", "factor": 2.0},
    )
    engine = started(profile)
    local = decoded("SET_POSITION_TARGET_LOCAL_NED", x=1.0, y=2.0, z=-5.0, coordinate_frame=1, type_mask=0xFF8)
    assert run(engine, local).fields == {"z": -8.0}
    glob = decoded("SET_POSITION_TARGET_GLOBAL_INT", lat_int=473977420, lon_int=85455940, alt=20.0,
                   coordinate_frame=6)  # fmt: skip
    assert run(engine, glob).fields == {"lat_int": 473978420, "alt": 40.0}  # lat_int in degrees: 1e-4 deg


def test_a_float_in_where_matches_the_float32_the_frame_carries() -> None:
    engine = started(make_profile({"target": up("COMMAND_LONG", "param7", {"param1": 0.1}), "kind": "set",
                                   "value": 1.0}))  # fmt: skip
    assert run(engine, command_long(ARM, param1=0.1)).fields == {"param7": 1.0}
    assert run(engine, command_long(ARM, param1=0.2)).untouched


def test_a_frame_rule_with_where_drops_only_the_matching_commands() -> None:
    engine = started(make_profile({"target": up("COMMAND_LONG", where={"command": "MAV_CMD_NAV_RETURN_TO_LAUNCH"}),
                                   "kind": "drop"}))  # fmt: skip
    assert run(engine, command_long(RTL)).drop
    assert run(engine, command_long(TAKEOFF)).untouched


def test_a_stateful_rule_sees_only_matching_frames() -> None:
    # freeze keeps the last value seen before its window: a frame the where rejects must not become it.
    engine = started(make_profile({"target": up("PARAM_SET", "param_value", {"param_id": "RTL_ALT"}),
                                   "kind": "freeze", "start_s": 1.0}))  # fmt: skip

    def param(name: str, value: float) -> tuple[int, dict[str, Any]]:
        return decoded("PARAM_SET", param_id=name, param_value=value, param_type=9)

    msgid, fields = param("RTL_ALT", 1500.0)
    assert engine.process(0.5, msgid, fields, UP, 255, 190).untouched
    msgid, fields = param("WPNAV_SPEED", 999.0)
    engine.process(0.7, msgid, fields, UP, 255, 190)
    msgid, fields = param("RTL_ALT", 3000.0)
    assert engine.process(2.0, msgid, fields, UP, 255, 190).fields == {"param_value": 1500.0}


BAD_WHERE = [
    ({"command": "MAV_CMD_NAV_TAKEOF"}, "rules[0].target.where.command", "closest: MAV_CMD_NAV_TAKEOFF"),
    ({"comand": 22}, "rules[0].target.where.comand", "closest: command"),
    ({"command": 70000}, "rules[0].target.where.command", "outside what uint16_t carries"),
    ({"command": [22, "NAV_TAKEOF"]}, "rules[0].target.where.command[1]", "closest: MAV_CMD_NAV_TAKEOFF"),
    ({"param1": "high"}, "rules[0].target.where.param1", "takes a number"),
    ({"command": 22.5}, "rules[0].target.where.command", "not a whole wire value"),
    ({}, "rules[0].target.where", "empty"),
]


@pytest.mark.parametrize(("where", "path", "says"), BAD_WHERE)
def test_a_bad_where_is_one_line_naming_the_closest(where: dict[str, Any], path: str, says: str) -> None:
    doc = {"name": "t", "rules": [{"target": up("COMMAND_LONG", "param7", where), "kind": "bias", "offset": 1}]}
    with pytest.raises(InputError) as info:
        parse_profile(doc, "p.yaml")
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"p.yaml: {path}: ") and says in text, text


def test_where_on_a_quantity_and_text_too_long_are_refused() -> None:
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.where: where needs a message target"):
        parse_profile({"name": "t", "rules": [{"target": {"quantity": "altitude", "where": {"x": 1}}, "kind": "bias",
                                               "offset": 1}]})  # fmt: skip
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.where\.param_id: PARAM_SET\.param_id is text of up"):
        parse_profile({"name": "t", "rules": [{"target": up("PARAM_SET", "param_value", {"param_id": "X" * 17}),
                                               "kind": "bias", "offset": 1}]})  # fmt: skip


def test_library_takeoff_altitude_covers_both_command_messages() -> None:
    engine = started(library.load("takeoff-altitude", altitude_m=40.0))
    assert run(engine, command_long(TAKEOFF, param7=5.0)).fields == {"param7": 40.0}
    frame = decoded("COMMAND_INT", command=TAKEOFF, frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, z=5.0)
    assert run(engine, frame).fields == {"z": 40.0}
    assert run(engine, command_long(ARM, param7=5.0)).untouched
    assert run(started(library.load("takeoff-altitude")), command_long(TAKEOFF, param7=5.0)).fields == {"param7": 12.0}


def _range(sensor_id: int, cm: int) -> tuple[int, dict[str, Any]]:
    return decoded("DISTANCE_SENSOR", id=sensor_id, current_distance=cm, min_distance=20, max_distance=4000,
                   orientation=25)  # fmt: skip


def test_library_vehicle_rangefinder_bias_toward_the_vehicle_only() -> None:
    every = started(library.load("vehicle-rangefinder-bias"))
    for sid in (0, 1, 7):
        assert run(every, _range(sid, 300)).fields == {"current_distance": 800}
    assert run(every, _range(0, 300), Direction.DOWNLINK).untouched
    one = started(library.load("vehicle-rangefinder-bias", sensor_id=1, offset_m=2.0))
    assert run(one, _range(1, 300)).fields == {"current_distance": 500}
    assert run(one, _range(0, 300)).untouched


_COMMANDS = sorted(mavlink.enums["MAV_CMD"])[:-1]  # every MAV_CMD but the ENUM_END marker
_params = st.floats(width=32, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(_COMMANDS), st.sampled_from(_COMMANDS), st.lists(_params, min_size=7, max_size=7),
       st.floats(-1e4, 1e4))  # fmt: skip
def test_where_acts_exactly_on_the_matching_commands(wanted: int, sent: int, params: list[float], alt: float) -> None:
    name = mavlink.enums["MAV_CMD"][wanted].name
    engine = started(make_profile({"target": up("COMMAND_LONG", "param7", {"command": name}), "kind": "set",
                                   "value": alt}))  # fmt: skip
    frame = command_long(sent, **{f"param{k + 1}": p for k, p in enumerate(params)})
    action = run(engine, frame)
    if sent != wanted:
        assert action.untouched
        return
    assert set(action.fields or {}) <= {"param7"}
    written = (action.fields or {}).get("param7", params[6])
    f32 = struct.Struct("<f")
    assert f32.unpack(f32.pack(written)) == f32.unpack(f32.pack(alt))  # the number the frame carries (-0.0 == 0.0)


_where_keys = st.sampled_from(["command", "param1", "param_id", "frame", "confirmation", "x", "", "distances[2]"])
_where_values = st.one_of(st.integers(-(2**70), 2**70), st.floats(), st.text(max_size=20), st.booleans(),
                          st.sampled_from(["NAV_TAKEOFF", "MAV_CMD_NAV_LAND", "MAV_FRAME_GLOBAL"]))  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(["COMMAND_LONG", "COMMAND_INT", "PARAM_SET"]),
       st.dictionaries(_where_keys | st.text(max_size=8), _where_values | st.lists(_where_values, max_size=3),
                       max_size=3))  # fmt: skip
def test_any_where_is_accepted_or_refused_in_one_line_naming_it(message: str, where: dict[str, Any]) -> None:
    field = {"COMMAND_LONG": "param7", "COMMAND_INT": "z", "PARAM_SET": "param_value"}[message]
    doc = {"name": "t", "rules": [{"target": up(message, field, where), "kind": "bias", "offset": 1}]}
    try:
        profile = parse_profile(doc, "p.yaml")
    except InputError as err:
        assert "\n" not in str(err) and str(err.field).startswith("rules[0].target.where"), str(err)
        return
    started(profile)  # what was accepted also builds

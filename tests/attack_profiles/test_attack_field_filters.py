"""Engine.field_filters: which untargeted frames the engine may never see, and that it then behaves the same.

The proxy keeps a DISTANCE_SENSOR frame of a sensor no rule names out of the engine (in C on the fast path,
undecoded on the Python one) when the engine says so. The property: over any stream, an engine fed only the
frames its filters keep returns, frame for frame, what an engine fed everything returns, and everything the
filters leave out comes back untouched from the engine that saw it.
"""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from attack_profiles import Action, Direction, Engine
from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Packet
from tests.support.attack_helpers import make_profile, rule
from tests.support.frames_support import local_position, pack
from tests.support.frames_support import mavlink as mavlink_dialect

DS = 132


def test_a_rule_on_named_sensors_filters_on_the_id_field() -> None:
    engine = Engine(make_profile(rule("bias", [3, 1], offset_m=0.5), rule("set", 7, value=2.0)))
    assert engine.field_filters == {DS: ("id", frozenset({1, 3, 7}))}


def test_what_needs_every_frame_of_the_message_gets_no_filter() -> None:
    assert Engine(make_profile(rule("bias", None, offset_m=0.5))).field_filters == {}  # every sensor
    assert Engine(make_profile(rule("bias", 1, offset_m=0.5), rule("drop", None))).field_filters == {}
    # A RANGEFINDER rule learns the primary rangefinder's limits from every DISTANCE_SENSOR.
    rf = rule("bias", None, message="RANGEFINDER", offset_m=1.0)
    assert Engine(make_profile(rule("bias", 1, offset_m=0.5), rf)).field_filters == {}
    # A duplicate takes whole messages.
    dup = {"target": {"message": "DISTANCE_SENSOR"}, "kind": "duplicate", "copies": 1}
    assert Engine(make_profile(rule("bias", 1, offset_m=0.5), dup)).field_filters == {}


def test_the_vehicle_clock_filters_only_while_nothing_reads_another_frames_time() -> None:
    ds = rule("bias", 1, offset_m=0.5)
    assert Engine(make_profile(ds, clock="vehicle")).field_filters == {DS: ("id", frozenset({1}))}
    # GPS_RAW_INT carries time_usec, which may be a UNIX time: then it takes the last boot time any frame brought.
    gps = rule("bias", None, message="GPS_RAW_INT", target_field="alt", offset_m=1.0)
    assert Engine(make_profile(ds, gps, clock="vehicle")).field_filters == {}
    assert Engine(make_profile(ds, gps)).field_filters == {DS: ("id", frozenset({1}))}


SIDS = st.integers(0, 5)
VALUE_RULES = st.sampled_from([
    {"kind": "bias", "offset_m": 0.5}, {"kind": "scale", "factor": 1.5}, {"kind": "freeze"},
    {"kind": "noise", "std": 0.3}, {"kind": "drop", "probability": 0.5}, {"kind": "delay", "delay_s": 0.2},
    {"kind": "ramp", "rate_per_s": 0.1}, {"kind": "intermittent", "on_s": 0.3, "off_s": 0.2},
])  # fmt: skip


@st.composite
def _profiles(draw: st.DrawFn) -> Any:
    rules = []
    for _ in range(draw(st.integers(1, 3))):
        sid = draw(st.none() | SIDS | st.lists(SIDS, min_size=1, max_size=3))
        body = dict(draw(VALUE_RULES))
        kind = body.pop("kind")
        window = {"start_s": draw(st.sampled_from([0.0, 0.5]))}
        rules.append(rule(kind, sid, **body, **window))
    extra = draw(st.sampled_from(["none", "position", "gps", "rangefinder"]))
    if extra == "position":
        rules.append(rule("bias", None, message="LOCAL_POSITION_NED", target_field="z", offset_m=1.0))
    elif extra == "gps":
        rules.append(rule("ramp", None, message="GPS_RAW_INT", target_field="alt", rate_per_s=1.0))
    elif extra == "rangefinder":
        rules.append(rule("bias", None, message="RANGEFINDER", offset_m=1.0))
    return make_profile(*rules, clock=draw(st.sampled_from(["activation", "vehicle"])), seed=draw(st.integers(0, 9)))


def _frame(kind: str, sid: int, cm: int, t_ms: int) -> bytes:
    if kind == "ds":  # even sensors look down (ArduPilot's primary rangefinder, which RANGEFINDER mirrors), each
        # with limits of its own; sensor 4 says its reading is invalid
        return pack(mavlink_dialect.MAVLink_distance_sensor_message(
            t_ms, 10 + 60 * sid, 4000 - 500 * sid, cm, 0, sid, 25 * (1 - sid % 2), 0,
            signal_quality=1 if sid == 4 else 0))
    if kind == "pos":
        return pack(local_position(z=-cm / 100.0))
    if kind == "gps":  # time_usec a UNIX time half the time: the vehicle clock falls back on another frame's
        return pack(mavlink_dialect.MAVLink_gps_raw_int_message(
            t_ms * 1000 + (1_700_000_000_000_000 if sid % 2 else 0), 3, 1, 2, 3000, 1, 1, 0, 0, 9))  # fmt: skip
    return pack(mavlink_dialect.MAVLink_rangefinder_message(cm / 100.0, 0.0))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# Where a filter would be wrong: the primary rangefinder's limits come from another sensor's frame, the
# vehicle clock of a GPS frame with a UNIX time from another sensor's boot time.
@example(make_profile(rule("bias", 1, offset_m=0.5), rule("bias", None, message="RANGEFINDER", offset_m=1.0)),
         [("ds", 0, 100, 0), ("rf", 0, 4500, 10)])
@example(make_profile(rule("bias", 1, offset_m=0.5), rule("ramp", None, message="GPS_RAW_INT", target_field="alt",
                                                          rate_per_s=1.0), clock="vehicle"),
         [("ds", 0, 100, 0), ("gps", 1, 0, 10)])  # fmt: skip
@given(_profiles(), st.lists(st.tuples(st.sampled_from(["ds", "ds", "ds", "pos", "gps", "rf"]), SIDS,
                                       st.integers(0, 5000), st.integers(0, 300)), min_size=1, max_size=40))
def test_an_engine_that_never_sees_the_filtered_frames_acts_as_one_that_saw_them(profile: Any,
                                                                                  stream: list[Any]) -> None:
    full, lean = Engine(profile, seed=1), Engine(profile, seed=1)
    full.activate(0.0)
    lean.activate(0.0)
    filters = lean.field_filters
    t_ms = 1000
    for kind, sid, cm, step_ms in stream:
        t_ms += step_ms
        raw = _frame(kind, sid, cm, t_ms)
        header, raw = split(raw).frames[0]
        if header.msgid not in full.message_ids:
            continue
        fields = codec.decode(Packet(raw, header, Direction.DOWNLINK, 0, 0.0))
        now_s = t_ms / 1000.0
        a = full.process(now_s, header.msgid, fields, Direction.DOWNLINK, 1, 1)
        flt = filters.get(header.msgid)
        if flt is not None and fields[flt[0]] not in flt[1]:
            assert a == Action(), (kind, sid)  # what the filter leaves out, the engine would have left alone
            continue
        b = lean.process(now_s, header.msgid, fields, Direction.DOWNLINK, 1, 1)
        assert a == b, (kind, sid)

"""Engine.memo_fields and Engine.steady_until: when the proxy may repeat a verdict without asking the engine.

The fast route remembers, after the engine rewrote a frame, "a frame of this key whose payload less its time
field is this one's leaves rewritten so", and repeats it until ``steady_until``. The property that makes that
exact: every frame equal to the one processed but for the field ``memo_fields`` leaves out, processed at any
time before ``steady_until``, gets the same Action. And ``steady_until`` is no shorter than it must be: it
falls where a window on the frame's chain opens or closes.
"""

from __future__ import annotations

import math
from typing import Any

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from attack_profiles import Direction, Engine
from attack_profiles.engine import Window
from attack_profiles.profile import Profile
from secuav_common.scenario import load_scenario
from tests.support.attack_helpers import distance, make_profile, rule

DS, RANGEFINDER, LOCAL_POSITION_NED, GLOBAL_POSITION_INT = 132, 173, 32, 33
DOWN, UP = Direction.DOWNLINK, Direction.UPLINK
WALL = load_scenario("wall_hover")  # sensors 0-5, each with a noise of its own (offset_sigmas)
T0 = 1000.0  # the monotonic time the profile is activated at


def memo(*rules: dict[str, Any], clock: str = "activation") -> dict[int, str | None]:
    return Engine(make_profile(*rules, clock=clock), scenario=WALL).memo_fields


# -- memo_fields ------------------------------------------------------------------------------------------


def test_pure_value_rules_leave_the_time_field_out_of_the_key() -> None:
    assert memo(rule("bias", 1, offset_m=0.5)) == {DS: "time_boot_ms"}
    assert memo(rule("bias", None, offset_sigmas=2.0)) == {DS: "time_boot_ms"}
    assert memo(rule("set", [1, 2], value=3.0), rule("scale", None, factor=1.5)) == {DS: "time_boot_ms"}
    # out_of_range: attack changes what is written, not whether it is a function of the payload
    assert memo(rule("bias", 1, offset_m=0.5, out_of_range="attack", start_s=2.0, end_s=3.0)) == {DS: "time_boot_ms"}
    # GLOBAL_POSITION_INT under the activation clock; a message without a time field is keyed whole
    assert memo(rule("bias", None, message="GLOBAL_POSITION_INT", target_field="relative_alt", offset_m=1.0),
                rule("bias", None, message="VFR_HUD", target_field="groundspeed", offset_m=1.0),
                ) == {GLOBAL_POSITION_INT: "time_boot_ms", 74: None}  # fmt: skip


def test_a_time_field_something_reads_or_writes_stays_in_the_key() -> None:
    assert memo(rule("bias", 1, offset_m=0.5, target_where={"time_boot_ms": 5})) == {DS: None}
    assert memo(rule("bias", 1, offset_m=0.5), rule("set", 2, value=7.0, target_field="time_boot_ms")) == {DS: None}


def test_what_depends_on_more_than_the_payload_is_not_repeated() -> None:
    for kind, params in [("ramp", {"rate_per_s": 0.1}), ("noise", {"std": 0.3}), ("drop", {}),
                         ("delay", {"delay_s": 0.2}), ("freeze", {}), ("sinusoid", {"amplitude": 1.0, "period_s": 2.0}),
                         ("intermittent", {"on_s": 0.3, "off_s": 0.2}), ("garbage", {})]:  # fmt: skip
        assert memo(rule("bias", 1, offset_m=0.5), rule(kind, 2, **params)) == {}, kind
    spoof = rule("coordinated_spoof", [11], velocity_ned_m_s=[0.0, 0.5, 0.0])
    assert Engine(make_profile(spoof), scenario=load_scenario("anchors8")).memo_fields == {}
    # The primary rangefinder is learnt from every DISTANCE_SENSOR: neither is repeated.
    assert memo(rule("bias", 1, offset_m=0.5), rule("bias", None, message="RANGEFINDER", offset_m=1.0)) == {}
    # The position is learnt from LOCAL_POSITION_NED (a coordinated spoof reads it): not repeated either.
    assert LOCAL_POSITION_NED not in Engine(make_profile(
        rule("coordinated_spoof", [11], velocity_ned_m_s=[0.0, 0.5, 0.0]),
        rule("bias", None, message="LOCAL_POSITION_NED", target_field="z", offset_m=1.0)),
        scenario=load_scenario("anchors8")).memo_fields  # fmt: skip


def test_a_frame_operation_that_takes_the_message_takes_it_out() -> None:
    for op in ({"kind": "duplicate", "target": {"message": "DISTANCE_SENSOR"}, "copies": 1},
               {"kind": "frame_replay", "target": {"message": "DISTANCE_SENSOR"}, "record_start_s": 0.0,
                "record_end_s": 1.0, "start_s": 2.0}):  # fmt: skip
        assert memo(rule("bias", 1, offset_m=0.5), op) == {}, op["kind"]
    # An inject only sends frames of its own (it takes none, FrameOps.message_ids): the received ones stay
    # a function of their payload.
    inject = {"kind": "inject", "target": {"message": "DISTANCE_SENSOR", "direction": "downlink"},
              "fields": {"current_distance": 100, "id": 9}, "rate_hz": 1.0}  # fmt: skip
    engine = Engine(make_profile(rule("bias", 1, offset_m=0.5), inject))
    assert engine.frame_ops is not None and DS not in engine.frame_ops.message_ids
    assert engine.memo_fields == {DS: "time_boot_ms"}


def test_the_vehicle_clock_repeats_only_rules_always_on() -> None:
    assert memo(rule("bias", 1, offset_m=0.5), clock="vehicle") == {DS: "time_boot_ms"}
    assert memo(rule("bias", 1, offset_m=0.5, start_s=0.0, end_s=2.0, repeat_period_s=2.0), clock="vehicle") == {
        DS: "time_boot_ms"}  # fmt: skip
    assert memo(rule("bias", 1, offset_m=0.5, start_s=1.0), clock="vehicle") == {}
    assert memo(rule("bias", 1, offset_m=0.5, end_s=3.0), clock="vehicle") == {}
    # GPS_RAW_INT's time_usec may be a UNIX time: it then reads the last boot time another frame brought.
    gps = rule("bias", None, message="GPS_RAW_INT", target_field="alt", offset_m=1.0)
    assert memo(rule("bias", 1, offset_m=0.5), gps, clock="vehicle") == {}
    assert memo(rule("bias", 1, offset_m=0.5), gps) == {DS: "time_boot_ms", 24: "time_usec"}


# -- steady_until, by example -----------------------------------------------------------------------------


def test_steady_until_follows_the_windows_of_the_frames_chain() -> None:
    engine = Engine(make_profile(rule("bias", 1, offset_m=0.5, start_s=2.0, end_s=3.0, repeat_period_s=5.0),
                                 rule("set", 2, value=1.0)))  # fmt: skip
    assert engine.steady_until(T0, DS, distance(1, 200), DOWN, 1) is None  # not activated
    engine.activate(T0)
    assert math.isclose(engine.steady_until(T0 + 1.0, DS, distance(1, 200), DOWN, 1), T0 + 2.0, abs_tol=1e-5)
    assert math.isclose(engine.steady_until(T0 + 2.5, DS, distance(1, 200), DOWN, 1), T0 + 3.0, abs_tol=1e-5)
    assert math.isclose(engine.steady_until(T0 + 3.5, DS, distance(1, 200), DOWN, 1), T0 + 7.0, abs_tol=1e-5)
    assert engine.steady_until(T0 + 3.5, DS, distance(2, 200), DOWN, 1) == math.inf  # always on
    assert engine.steady_until(T0 + 3.5, DS, distance(3, 200), DOWN, 1) == math.inf  # no rule
    assert engine.steady_until(T0, 0, {}, DOWN, 1) is None  # not a message it vouches for
    assert engine.steady_until(T0 - 1.0, DS, distance(2, 200), DOWN, 1) <= T0  # before the clock's zero


def test_epoch_counts_activations() -> None:
    engine = Engine(make_profile(rule("bias", 1, offset_m=0.5)))
    assert engine.epoch == 0
    engine.activate(T0, rebuild=False)
    engine.activate(T0 + 1.0)
    assert engine.epoch == 2


# -- Window.next_edge against tau -------------------------------------------------------------------------

EPS = 1e-7
durations = st.floats(0.01, 20.0)


@st.composite
def windows(draw: st.DrawFn) -> Window:
    start = draw(st.sampled_from([0.0, 0.5]) | st.floats(0.0, 10.0))
    shape = draw(st.sampled_from(["forever", "once", "repeat", "on"]))
    if shape == "forever":
        return Window(start, math.inf, None)
    length = draw(durations)
    if shape == "once":
        return Window(start, length, None)
    return Window(start, length, length if shape == "on" else length + draw(durations))


def off(w: Window, t: float) -> bool:
    return w.tau(t) is None


@settings(max_examples=300, deadline=None)
@example(Window(0.0, math.inf, None), 0.0, [0.5])
@example(Window(2.0, 1.0, 5.0), 3.0, [0.5])  # exactly on an edge: the next one
@example(Window(2.0, 1.0, 5.0), 1.9999, [0.5])
@given(windows(), st.floats(-1.0, 60.0), st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8))
def test_next_edge_is_where_tau_next_turns(w: Window, t: float, fractions: list[float]) -> None:
    edge = w.next_edge(t)
    assert edge > t
    span = min(edge, t + 100.0) - EPS
    for f in fractions:  # nothing turns in [t, edge)
        x = t + f * (span - t)
        if x >= t:
            assert off(w, x) == off(w, t), (x, edge)
    if edge != math.inf:  # and it does turn there
        assert off(w, edge + EPS) != off(w, t)
    elif t >= 0.0:
        assert all(off(w, t + d) == off(w, t) for d in (1.0, 1e3, 1e6))


# -- the property: a frame equal but for its time field, before steady_until, gets the same verdict ---------

SIDS = st.integers(0, 5)


@st.composite
def pure_rules(draw: st.DrawFn, always_on: bool) -> dict[str, Any]:
    kind = draw(st.sampled_from(["bias", "bias_sigmas", "set", "scale"]))
    params: dict[str, Any] = {
        "bias": {"offset_m": draw(st.floats(-5.0, 5.0))},
        "bias_sigmas": {"offset_sigmas": draw(st.floats(-5.0, 5.0))},
        "set": {"value": draw(st.floats(0.0, 50.0))},
        "scale": {"factor": draw(st.floats(-2.0, 3.0))},
    }[kind]
    kind = kind.removesuffix("_sigmas")
    field = draw(st.sampled_from(["current_distance", "current_distance", "max_distance", "signal_quality",
                                  "quaternion[1]"]))  # fmt: skip
    if field == "signal_quality":
        kind, params = "set", {"value": float(draw(st.sampled_from([0, 1, 100])))}
    if not always_on:
        start = draw(st.sampled_from([0.0, 0.5, 2.0]) | st.floats(0.0, 5.0))
        params["start_s"] = start
        shape = draw(st.sampled_from(["forever", "once", "repeat"]))
        if shape != "forever":
            length = draw(st.floats(0.05, 3.0))
            params["end_s"] = start + length
            if shape == "repeat":
                gap = draw(st.sampled_from([0.0]) | st.floats(0.05, 3.0))  # 0: on for good once it starts
                params["repeat_period_s"] = (params["end_s"] - start) + gap
    extra: dict[str, Any] = {"target_field": field, "out_of_range": draw(st.sampled_from(["keep", "attack"]))}
    if draw(st.booleans()):
        extra["target_where"] = {"orientation": draw(st.sampled_from([0, 25]))}
    if draw(st.integers(0, 4)) == 0:
        extra["target_direction"] = draw(st.sampled_from(["uplink", "both"]))
    sid = draw(st.none() | SIDS | st.lists(SIDS, min_size=1, max_size=3, unique=True))
    return rule(kind, sid, **params, **extra)


@st.composite
def pure_profiles(draw: st.DrawFn) -> Profile:
    clock = draw(st.sampled_from(["activation", "activation", "vehicle"]))
    rules = draw(st.lists(pure_rules(always_on=clock == "vehicle"), min_size=1, max_size=4))
    if draw(st.booleans()):  # what another message's rules do is theirs alone
        rules.append(rule("ramp", None, message="GLOBAL_POSITION_INT", target_field="relative_alt", rate_per_s=1.0))
    return make_profile(*rules, clock=clock, seed=draw(st.integers(0, 9)))


@st.composite
def ds_fields(draw: st.DrawFn) -> dict[str, Any]:
    f = distance(draw(st.integers(0, 6)), draw(st.integers(0, 5000)), draw(st.integers(0, 2**32 - 1)))
    f["min_distance"] = draw(st.sampled_from([0, 10, 20, 300]))
    f["max_distance"] = draw(st.sampled_from([4000, 600, 100]))
    f["signal_quality"] = draw(st.sampled_from([0, 1, 100]))
    f["orientation"] = draw(st.sampled_from([0, 25]))
    return f


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(make_profile(rule("bias", 1, offset_m=0.5, start_s=2.0, end_s=3.0, repeat_period_s=5.0)),
         distance(1, 200, 77), 2.5, DOWN, [(0.0, None), (0.5, distance(1, 300, 9)), (0.999, None)])  # fmt: skip
@given(pure_profiles(), ds_fields(), st.floats(-0.5, 20.0), st.sampled_from([DOWN, UP]),
       st.lists(st.tuples(st.floats(0.0, 1.0), st.none() | ds_fields()), min_size=1, max_size=6))  # fmt: skip
def test_a_frame_equal_but_for_its_time_gets_the_same_verdict_until_steady_until(
    profile: Profile, a: dict[str, Any], t_a: float, direction: Direction, later: list[Any]
) -> None:
    """``later``: when each repeat comes (a fraction of the time to steady_until), and another frame the
    engine sees just before it (the fast route takes only the repeats)."""
    engine = Engine(profile, scenario=WALL)
    engine.activate(T0)
    assert DS in engine.memo_fields and engine.memo_fields[DS] == "time_boot_ms"
    now_s = T0 + t_a
    verdict = engine.process(now_s, DS, a, direction, 1, 1)
    until = engine.steady_until(now_s, DS, a, direction, 1)
    assert until is not None
    if profile.clock == "vehicle":
        assert until == math.inf
    span = min(until, now_s + 1e4) - 1e-6  # a microsecond clear of the edge
    for i, (f, other) in enumerate(later):
        b = dict(a, time_boot_ms=(a["time_boot_ms"] + 1 + 7919 * i) % 2**32)
        when = now_s + f * (span - now_s)
        if when >= now_s:
            if other is not None:
                engine.process(when, DS, other, direction, 1, 1)
            assert engine.process(when, DS, b, direction, 1, 7) == verdict, (when, until)
    # Not needlessly short: it ends where a window on the chain opens or closes.
    t = a["time_boot_ms"] * 1e-3 if profile.clock == "vehicle" else now_s - T0
    chain = [r for r in profile.rules if r.target.message == "DISTANCE_SENSOR"]
    chain = [r for r in chain if r.target.sensor_ids() is None or a["id"] in r.target.sensor_ids()]
    chain = [r for r in chain if r.target.direction in (direction.value, "both")]
    if until == math.inf:
        assert all(Window.of(r).next_edge(t) == math.inf for r in chain)
    else:
        edge = until - T0 + 1e-6  # the margin it keeps
        assert any(off(Window.of(r), t) != off(Window.of(r), edge + EPS) for r in chain)


def test_the_offset_in_sigmas_is_the_sensors_own() -> None:
    """Two sensors with different noise: each key has its own verdict, and each repeats it."""
    engine = Engine(make_profile(rule("bias", None, offset_sigmas=10.0)), scenario=WALL)
    engine.activate(T0)
    got = {sid: engine.process(T0 + 1.0, DS, distance(sid, 200, 5), DOWN, 1, 1).fields for sid in (2, 4)}
    assert got == {2: {"current_distance": 250}, 4: {"current_distance": 280}}
    assert engine.steady_until(T0 + 1.0, DS, distance(4, 200, 5), DOWN, 1) == math.inf

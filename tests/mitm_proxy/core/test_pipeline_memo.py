"""The fast route repeats only what the Python pipeline would do (mitm_proxy/core/pipeline.py, the module doc).

A pipeline with a real attack stage teaches a real C route (its ``learners``); a second pipeline with the same
profile and clock is the reference. Whatever the route answers itself, at whatever time, must be the reference's
bytes for that frame at that time; what it does not answer goes through the learning pipeline, which must give
the same bytes too. Profiles are random pure rules (bias, set, scale) with windows, periods and sensor ids.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavframe.packet import Direction
from mitm_proxy.core.pipeline import Pipeline
from tests.support.frames_support import heartbeat, mav, mavlink, pack, verdict_route
from tests.support.pipelines import bias, make

pytestmark = pytest.mark.usefixtures("fast_path")  # skipped where it is not built, a failure under CI

DOWN = Direction.DOWNLINK
DISTANCE_SENSOR = 132


def taught_route(pipe: Pipeline) -> Any:
    """A C route configured from the pipeline's fast wants, registered as its learner (no socket: verdict only)."""
    wants = pipe.fast_wanted(DOWN)
    assert wants is not None
    r = verdict_route(wants.ids, wants.filters, wants.memo)
    pipe.learners[DOWN] = [r.learn]
    return r


def started(*rules: dict[str, Any]) -> Pipeline:
    pipe, _, stage = make(*rules)
    engine = stage.slot.engine
    assert engine is not None
    engine.activate(0.0)  # the profile clock starts at monotonic 0 here
    return pipe


def joined(outs: list[Any]) -> bytes:
    assert all(o.release_s <= o.rx_s for o in outs)
    return b"".join(o.data for o in outs)


windows = st.one_of(
    st.just({}),
    st.builds(lambda a, n: {"start_s": a, "end_s": a + n}, st.floats(0, 5), st.floats(0.1, 5)),
    st.builds(lambda a, n, p: {"start_s": a, "end_s": a + n, "repeat_period_s": (a + n - a) + p},
              st.floats(0, 3), st.floats(0.1, 2), st.floats(0.0, 2)),
)
rules = st.builds(
    lambda kind, amount, sid, window, keep: {
        "target": {"message": "DISTANCE_SENSOR", **({} if sid is None else {"sensor_id": sid})},
        "kind": kind,
        **({"offset_m": amount} if kind == "bias" else {"value": abs(amount)} if kind == "set" else {"factor": amount}),
        "out_of_range": keep,
        **window,
    },
    st.sampled_from(["bias", "set", "scale"]),
    st.floats(-3, 3).filter(lambda x: abs(x) > 0.01),
    st.one_of(st.none(), st.integers(0, 2), st.lists(st.integers(0, 2), min_size=1, max_size=2)),
    windows,
    st.sampled_from(["keep", "attack"]),
)


@settings(max_examples=60, deadline=None)
@given(
    chosen=st.lists(rules, min_size=1, max_size=3),
    stream=st.lists(st.tuples(st.floats(0, 0.5), st.sampled_from([0, 5, 250, 251, 4000, 4100]),
                              st.integers(0, 2), st.integers(0, 2**32 - 1), st.booleans()),
                    min_size=1, max_size=40),
)
def test_the_route_answers_only_what_python_would(chosen: list[dict[str, Any]],
                                                  stream: list[tuple[float, int, int, int, bool]]) -> None:  # fmt: skip
    reference, learning = started(*chosen), started(*chosen)
    route = taught_route(learning)
    engine = learning.stages[0].slot.engine  # type: ignore[attr-defined]
    wants = learning.fast_wanted(DOWN)
    assert wants is not None
    memo = wants.memo
    m = mav()
    now = 0.0
    for step, cm, sid, t_ms, with_heartbeat in stream:
        now += step
        msg = mavlink.MAVLink_distance_sensor_message(t_ms, 10, 4000, cm, 0, sid, 25, 255)
        frame = pack(msg, m) + (pack(heartbeat(), m) if with_heartbeat else b"")
        want = joined(reference.feed(frame, DOWN, now))
        got = route.verdict(frame, now)
        if got is not None:
            assert got[0] == want
        else:
            assert joined(learning.feed(frame, DOWN, now)) == want
            until = engine.steady_until(now, DISTANCE_SENSOR, msg.to_dict(), DOWN, 1)
            if DISTANCE_SENSOR in memo and until is not None and until > now:  # taught: the route answers it now
                again = route.verdict(frame, now)
                assert again is not None and again[0] == want


def test_a_steady_bias_is_answered_by_the_route_after_one_frame_of_each_key() -> None:
    pipe = started(bias(sensor_id=0, offset_m=1.0))
    route = taught_route(pipe)
    m = mav()
    sent = [pack(mavlink.MAVLink_distance_sensor_message(1000 + i, 10, 4000, 250 + i % 3, 0, 0, 25, 255), m)
            for i in range(30)]  # fmt: skip
    answered = 0
    for i, frame in enumerate(sent):
        got = route.verdict(frame, 1.0 + i * 0.01)
        if got is None:
            pipe.feed(frame, DOWN, 1.0 + i * 0.01)
        else:
            answered += 1
            assert got[1] == 1  # counted as a rewrite
    assert answered == 27  # all but the first of each of the three distances


def test_a_windowed_rule_is_repeated_until_its_end_and_then_left_alone() -> None:
    pipe = started(bias(sensor_id=0, offset_m=1.0) | {"end_s": 2.0})
    route = taught_route(pipe)
    m = mav()
    frame = pack(mavlink.MAVLink_distance_sensor_message(1000, 10, 4000, 250, 0, 0, 25, 255), m)
    pipe.feed(frame, DOWN, 1.0)
    assert route.verdict(frame, 1.5) is not None
    assert route.verdict(frame, 2.0) is None  # the window's end: Python decides again
    pipe.feed(frame, DOWN, 2.5)  # past the window: left as it came, and so it stays
    assert route.verdict(frame, 100.0) == (frame, 0)


def test_a_stage_that_wants_the_message_too_keeps_it_out_of_the_memory() -> None:
    from mitm_proxy.stages.attack import AttackStage

    pipe, _, stage = make(bias(sensor_id=0, offset_m=1.0))
    assert stage.slot.engine is not None
    other, _, _ = make({"target": {"message": "DISTANCE_SENSOR"}, "kind": "noise", "std": 0.1})
    second = other.stages[0]
    assert isinstance(second, AttackStage)
    both = Pipeline(0, [stage, second], stats=pipe.stats)
    wants = both.fast_wanted(DOWN)
    assert wants is not None and DISTANCE_SENSOR in wants.ids and DISTANCE_SENSOR not in wants.memo

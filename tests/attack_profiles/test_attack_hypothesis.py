"""Properties over the whole input space: valid profiles round-trip, garbage is rejected cleanly."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from attack_profiles import Direction, Engine, Profile, parse_profile
from attack_profiles.units import MESSAGES
from secuav_common.loading import InputError
from tests.support.attack_helpers import distance

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
positive = st.floats(1e-3, 1e4, allow_nan=False, allow_infinity=False)
times = st.floats(0.0, 1e4, allow_nan=False, allow_infinity=False)
ids = st.integers(0, 255)


@st.composite
def targets(draw: st.DrawFn, frame_level: bool) -> dict[str, Any]:
    message = draw(st.sampled_from(sorted(MESSAGES)))
    spec = MESSAGES[message]
    target: dict[str, Any] = {"message": message}
    fields = sorted(spec.fields)
    if spec.default_field is not None or frame_level:
        field = draw(st.none() | st.sampled_from(fields))
    else:
        field = draw(st.sampled_from(fields))
    if field is not None:
        target["field"] = field
    if spec.id_field is not None:
        sid = draw(
            st.none()
            | ids
            | st.lists(ids, min_size=1, max_size=4)
            | st.tuples(ids, ids).map(lambda p: {"first": min(p), "last": max(p)})
        )
        if sid is not None:
            target["sensor_id"] = sid
    target["direction"] = draw(st.sampled_from(["downlink", "uplink", "both"]))
    if draw(st.booleans()):
        target["sysid"] = draw(st.integers(0, 255))
    return target


@st.composite
def windows(draw: st.DrawFn) -> dict[str, Any]:
    start = draw(times)
    out: dict[str, Any] = {"start_s": start}
    if draw(st.booleans()):
        length = draw(positive)
        out["end_s"] = start + length
        if out["end_s"] > start and draw(st.booleans()):
            out["repeat_period_s"] = (out["end_s"] - start) * draw(st.floats(1.0, 10.0))
    return out


PARAMS: dict[str, Any] = {
    "bias": st.fixed_dictionaries({"offset": finite}),
    "ramp": st.fixed_dictionaries({"rate_per_s": finite}, optional={"offset": finite}),
    "sinusoid": st.fixed_dictionaries({"amplitude": finite, "period_s": positive}, optional={"phase_deg": finite}),
    "noise": st.fixed_dictionaries(
        {"std": st.floats(0, 100)}, optional={"distribution": st.sampled_from(["gaussian", "uniform"])}
    ),
    "scale": st.fixed_dictionaries({"factor": finite}),
    "set": st.fixed_dictionaries({"value": finite}),
    "freeze": st.just({}),
    "delay": st.fixed_dictionaries({"delay_s": st.floats(1e-3, 60.0)}),
    "drop": st.fixed_dictionaries({}, optional={"probability": st.floats(0.0, 1.0)}),
    "intermittent": st.fixed_dictionaries({"on_s": positive, "off_s": positive}),
    "garbage": st.just({}),
}
FRAME = {"delay", "drop", "intermittent"}


@st.composite
def rules(draw: st.DrawFn) -> dict[str, Any]:
    kind = draw(st.sampled_from([*PARAMS, "replay", "coordinated_spoof"]))
    if kind == "coordinated_spoof":
        links = draw(st.lists(st.integers(10, 49), min_size=1, max_size=4))
        target = {"message": "DISTANCE_SENSOR", "sensor_id": links}
        vec = st.tuples(finite, finite, finite).map(list)
        return {"target": target, "kind": kind, "velocity_ned_m_s": draw(vec), "offset_ned_m": draw(vec)}
    target = draw(targets(kind in FRAME))
    window = draw(windows())
    if kind == "replay":
        src_start = draw(st.floats(0.0, 100.0))
        src_end = src_start + draw(positive)
        window["start_s"] = max(window["start_s"], src_end)
        window.pop("end_s", None)
        window.pop("repeat_period_s", None)
        return {"target": target, "kind": kind, "source_start_s": src_start, "source_end_s": src_end, **window}
    return {"target": target, "kind": kind, **draw(PARAMS[kind]), **window}


profiles = st.fixed_dictionaries(
    {"name": st.text(min_size=1, max_size=20), "rules": st.lists(rules(), max_size=5)},
    optional={
        "description": st.text(max_size=40),
        "clock": st.sampled_from(["activation", "vehicle"]),
        "seed": st.integers(0, 2**40),
    },
)


@FAST
@given(profiles)
def test_any_valid_profile_round_trips_through_json(doc: dict[str, Any]) -> None:
    profile = parse_profile(doc, "<hypothesis>")
    text = json.dumps(profile.model_dump(mode="json"))
    again = parse_profile(text, "<json>")
    assert again == profile
    assert again.content_hash() == profile.content_hash()


@FAST
@given(profiles, st.integers(0, 65535), st.integers(0, 255), st.floats(0, 1e4))
def test_any_valid_profile_yields_wire_values_that_fit(doc: dict[str, Any], cm: int, sid: int, t: float) -> None:
    profile = parse_profile(doc, "<hypothesis>")
    if any(r.kind == "coordinated_spoof" for r in profile.rules):
        return  # needs a scenario; covered by its own tests
    engine = Engine(profile)
    engine.activate(0.0)
    action = engine.process(t, 132, distance(sid, cm, time_boot_ms=int(t * 1000)), Direction.DOWNLINK, 1, 1)
    for name, value in (action.fields or {}).items():
        spec = MESSAGES["DISTANCE_SENSOR"].fields[name]
        assert spec.lo <= value <= spec.hi
        assert isinstance(value, int) == spec.integer


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=20,
)
keyish = st.sampled_from(
    ["name", "rules", "target", "kind", "message", "field", "sensor_id", "start_s", "end_s", "offset", "clock", "x"]
)


def _assert_clean_rejection_or_profile(doc: Any) -> None:
    try:
        result = parse_profile(doc, "<garbage>")
    except InputError as err:
        assert err.field, f"error names no field: {err}"
        assert "\n" not in str(err)
        return
    assert isinstance(result, Profile)


@FAST
@given(json_values.filter(lambda doc: not isinstance(doc, str)))  # text: see the last test
def test_random_garbage_is_rejected_naming_a_field(doc: Any) -> None:
    _assert_clean_rejection_or_profile(doc)


@st.composite
def mutated(draw: st.DrawFn) -> Any:
    """A valid profile with one value somewhere replaced by garbage, or one key renamed."""
    doc = draw(profiles)
    node: Any = doc
    while isinstance(node, dict | list) and node and draw(st.booleans()):
        key = draw(st.sampled_from(sorted(node) if isinstance(node, dict) else list(range(len(node)))))
        if not isinstance(node[key], dict | list) or draw(st.booleans()):
            if isinstance(node, dict) and draw(st.booleans()):
                node[draw(keyish)] = node.pop(key)
            else:
                node[key] = draw(json_values)
            break
        node = node[key]
    return doc


@FAST
@given(mutated())
def test_mutated_profiles_are_rejected_naming_a_field_or_still_valid(doc: Any) -> None:
    _assert_clean_rejection_or_profile(doc)


@FAST
@given(st.text(max_size=200) | st.binary(max_size=200))
def test_random_text_never_raises_anything_but_input_error(text: str | bytes) -> None:
    try:
        parse_profile(text, "<text>")
    except InputError as err:
        assert "\n" not in str(err)

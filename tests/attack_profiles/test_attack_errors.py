"""Every bad profile is one line naming the file, the rule, the field and the bad value."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from attack_profiles import Engine, load_profile, parse_profile
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario
from tests.support.attack_helpers import make_profile, rule

GOOD = {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "bias", "offset": 1.0}


def _doc(*rules: dict) -> dict:
    return {"name": "bad", "rules": [GOOD, *rules]}


CASES = [
    # (bad rule, field path, value shown)
    ({**GOOD, "target": {"message": "DISTANCE_SENSR"}}, "rules[1].target.message", "'DISTANCE_SENSR'"),
    ({**GOOD, "target": {"message": "DISTANCE_SENSOR", "field": "distance"}}, "rules[1].target.field", "'distance'"),
    ({**GOOD, "start_s": 5.0, "end_s": 2.0}, "rules[1].end_s", "2.0"),
    ({**GOOD, "start_s": -1.0}, "rules[1].start_s", "-1.0"),
    ({**GOOD, "kind": "jam"}, "rules[1].kind", "'jam'"),
    ({"target": GOOD["target"], "kind": "noise", "std": -0.1}, "rules[1].std", "-0.1"),
    ({"target": GOOD["target"], "kind": "drop", "probability": 1.5}, "rules[1].probability", "1.5"),
    ({"target": GOOD["target"], "kind": "sinusoid", "amplitude": 1, "period_s": 0}, "rules[1].period_s", "0"),
    ({"target": GOOD["target"], "kind": "delay", "delay_s": 600}, "rules[1].delay_s", "600"),
    ({**GOOD, "offset": "far"}, "rules[1].offset", "'far'"),
    ({**GOOD, "offst": 1.0}, "rules[1].offst", "1.0"),
    ({**GOOD, "end_s": 3.0, "repeat_period_s": 2.0}, "rules[1].repeat_period_s", "2.0"),
    ({**GOOD, "repeat_period_s": 2.0}, "rules[1].repeat_period_s", "2.0"),
    (
        {"target": GOOD["target"], "kind": "replay", "source_start_s": 0, "source_end_s": 5, "start_s": 2},
        "rules[1].source_end_s",
        "5.0",
    ),
    (
        {"target": {"message": "LOCAL_POSITION_NED", "sensor_id": 3, "field": "x"}, "kind": "bias", "offset": 1},
        "rules[1].target.sensor_id",
        "3",
    ),
    ({"target": {"message": "LOCAL_POSITION_NED"}, "kind": "bias", "offset": 1}, "rules[1].target.field", ""),
    (
        {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 3}, "kind": "coordinated_spoof"},
        "rules[1].target.sensor_id",
        "3",
    ),
    (
        {"target": {"message": "DISTANCE_SENSOR", "sensor_id": {"first": 14, "last": 11}}, **{"kind": "freeze"}},
        "rules[1].target.sensor_id.last",
        "11",
    ),
    ({**GOOD, "target": {"message": "DISTANCE_SENSOR", "sensor_id": 300}}, "rules[1].target.sensor_id", "300"),
    # A union value is judged by the member its shape asks for, at the path the user wrote.
    (
        {**GOOD, "target": {"message": "DISTANCE_SENSOR", "sensor_id": {"first": 1}}},
        "rules[1].target.sensor_id.last",
        "",
    ),
    ({**GOOD, "target": {"message": "DISTANCE_SENSOR", "sensor_id": [1, "x"]}}, "rules[1].target.sensor_id[1]", "'x'"),
    ({**GOOD, "": 1}, "rules[1]['']", "1"),
]


@pytest.mark.parametrize(("bad", "where", "shown"), CASES)
def test_bad_rule_names_file_rule_field_and_value(tmp_path: Path, bad: dict, where: str, shown: str) -> None:
    path = tmp_path / "attack.json"
    path.write_text(json.dumps(_doc(bad)))
    with pytest.raises(InputError) as info:
        load_profile(path)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"{path}: {where}:"), text
    assert shown in text


def test_yaml_syntax_error_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nrules: [\n  {kind: bias\n")
    with pytest.raises(InputError, match=r"broken\.yaml: .*line \d+"):
        load_profile(path)


def test_missing_file_and_non_mapping() -> None:
    with pytest.raises(InputError, match=r"^/no/such\.yaml: No such file"):
        load_profile("/no/such.yaml")
    with pytest.raises(InputError, match=r"^<mqtt>: profile: a profile must be a mapping"):
        parse_profile("[1, 2]")
    with pytest.raises(InputError, match=r"^<mqtt>: profile: document is empty"):
        parse_profile("")


def test_unknown_parameter_reference_names_its_place() -> None:
    doc = {"name": "t", "parameters": {"a": {"default": 1}}, "rules": [{**GOOD, "offset": "$b"}]}
    with pytest.raises(InputError, match=r"rules\[0\]\.offset: no parameter 'b' \(declared: a\)"):
        parse_profile(doc)


def test_scenario_checks_name_rule_and_id() -> None:
    wall = load_scenario("wall_hover")
    with pytest.raises(InputError, match=r"test\.yaml: rules\[1\]\.target\.sensor_id: .*wall-hover.*\(got 7\)"):
        Engine(make_profile(rule("bias", offset=1.0), rule("bias", sensor_id=[4, 7], offset=1.0)), scenario=wall)
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.sysid: .*no such vehicle \(got 3\)"):
        Engine(make_profile(rule("bias", offset=1.0, target_sysid=3)), scenario=wall)
    spoof = make_profile(rule("coordinated_spoof", sensor_id=[11]))
    with pytest.raises(InputError, match=r"rules\[0\]\.kind: needs a scenario"):
        Engine(spoof)
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.sensor_id.*\(got 11\)"):
        Engine(spoof, scenario=wall)


def test_scenario_check_knows_a_companions_fed_sensors() -> None:
    """companion_feed's rangefinders 0 and 1 are fed to the vehicle by secuav-feed (``external``), not its own."""
    fed = load_scenario("companion_feed")
    assert not fed.vehicles[0].sensors.rangefinders
    engine = Engine(make_profile(rule("noise", sensor_id=[0, 1], std=0.1)), scenario=fed)
    assert engine.scenario is fed
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.sensor_id: .*\(ids: \[0, 1\]\).*\(got 2\)"):
        Engine(make_profile(rule("bias", sensor_id=[2], offset=1.0)), scenario=fed)


def test_nothing_half_applied_a_late_error_rejects_the_whole_profile() -> None:
    good_rules = [GOOD] * 5
    with pytest.raises(InputError, match=r"rules\[5\]"):
        parse_profile({"name": "t", "rules": [*good_rules, {**GOOD, "end_s": -1}]})


def test_scenario_check_accepts_a_range_that_reaches_some_sensor_only() -> None:
    anchors8 = load_scenario("anchors8")
    Engine(make_profile(rule("bias", sensor_id={"first": 10, "last": 49}, offset=1.0)), scenario=anchors8)
    far = make_profile(rule("bias", sensor_id={"first": 30, "last": 49}, offset=1.0))
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.sensor_id: .*no sensor in this range"):
        Engine(far, scenario=anchors8)


def test_only_whole_placeholder_strings_are_substituted() -> None:
    doc = {"name": "t", "parameters": {"o": {"default": 2.0}}, "rules": [{**GOOD, "offset": "$o", "note": "$5 and $o"}]}
    profile = parse_profile(doc)
    assert profile.rules[0].offset == 2.0  # type: ignore[union-attr]
    assert profile.rules[0].note == "$5 and $o"


DESIGN_EXAMPLE = """
name: wall-spoof-ramp
clock: activation          # or: vehicle (time_boot_ms of the stream)
rules:
  - target: {message: DISTANCE_SENSOR, sensor_id: 0, field: current_distance}
    kind: ramp             # bias | ramp | sinusoid | noise | scale | set | freeze | replay | delay | drop
    rate_per_s: 0.2        # metres per second in the field's physical unit
    start_s: 10
    end_s: 40
  - target: {message: DISTANCE_SENSOR, sensor_id: 12, field: current_distance}
    kind: bias
    offset_m: 2.0          # no end_s: until the profile is cleared
    start_s: 0
"""


def test_the_design_md_example_is_a_valid_profile() -> None:
    profile = parse_profile(DESIGN_EXAMPLE, "example.yaml")
    assert [r.kind for r in profile.rules] == ["ramp", "bias"]
    assert profile.rules[1].offset == 2.0  # type: ignore[union-attr]

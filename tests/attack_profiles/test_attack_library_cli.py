"""The library of ready profiles, the exported schema and the secuav-attack CLI."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from attack_profiles import Engine, library
from attack_profiles.cli import build_parser, main
from attack_profiles.primitives import BUILTIN_KINDS, PRIMITIVES, Primitive
from attack_profiles.profile import SCHEMA_PATH, profile_json_schema, profile_schema_text
from attack_profiles.rule import RuleBase
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario

REQUIRED = {
    "none",
    "type-a",
    "type-b",
    *(f"distance-{k}" for k in ("off", "stuck", "garbage", "wrong", "slow", "delayed", "intermittent")),
    *(f"position-{k}" for k in ("off", "stuck", "garbage", "wrong", "slow", "delayed", "intermittent")),
    "gps-glitch",
    "rangefinder-glitch",
    "drift",
    "wall-spoof",
    "wall-spoof-two",
    "anchors-constant",
    "anchors-ramp",
    "anchors-coordinated",
    "gps-drift",
}

# Which bundled scenario each seed profile is written for.
SCENARIO_OF = {
    "wall-spoof": "wall_hover",
    "wall-spoof-two": "wall_hover",
    "anchors-constant": "anchors8",
    "anchors-ramp": "anchors8",
    "anchors-coordinated": "anchors8",
    "type-a": "anchors8",
    "type-b": "anchors8",
}


def test_library_has_the_promised_profiles() -> None:
    assert set(library.names()) >= REQUIRED


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_every_library_profile_loads_builds_and_has_a_one_line_description(name: str) -> None:
    profile = library.load(name)
    assert profile.name == name
    assert profile.description and "\n" not in profile.description
    scenario = load_scenario(SCENARIO_OF.get(name, "anchors8"))
    Engine(profile, scenario=scenario)


def test_type_a_and_b_say_they_are_our_reading() -> None:
    for name in ("type-a", "type-b"):
        assert "our reading" in library.load(name).description.lower()


def test_library_parameters_override_and_are_recorded() -> None:
    profile = library.load("type-a", links=[12, 17], offset_m=2.0)
    rule = profile.rules[0]
    assert rule.target.sensor_ids() == frozenset({12, 17})
    assert rule.offset == 2.0  # type: ignore[union-attr]
    assert profile.parameters["links"].default == [12, 17]
    assert profile.content_hash() != library.load("type-a").content_hash()


def test_library_rejects_unknown_names_and_parameters() -> None:
    with pytest.raises(InputError, match="no such library profile"):
        library.load("nope")
    with pytest.raises(InputError, match="links_typo"):
        library.load("type-a", links_typo=[1])
    with pytest.raises(InputError, match=r"rules\[0\]\.target\.sensor_id"):
        library.load("type-a", links="eleven")


def test_wall_spoof_rejects_anchor_scenario_ids_by_rule() -> None:
    with pytest.raises(InputError, match=r"library:type-a: rules\[0\]\.target\.sensor_id.*got 11"):
        Engine(library.load("type-a"), scenario=load_scenario("wall_hover"))


def test_exported_schema_is_up_to_date() -> None:
    assert SCHEMA_PATH.read_text() == profile_schema_text(), (  # the built-ins' schema; the CLI's adds plugins
        f"regenerate: .venv/bin/python -c 'from attack_profiles.profile import profile_schema_text; "
        f"open(\"{SCHEMA_PATH}\", \"w\").write(profile_schema_text())'"
    )
    kinds = json.dumps(profile_json_schema())
    for kind in ("bias", "ramp", "coordinated_spoof", "intermittent"):
        assert f'"{kind}"' in kinds


def test_cli_validate_ok_and_bad(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.yaml"
    good.write_text(library.text("wall-spoof"))
    assert main(["validate", str(good), "--scenario", "wall_hover"]) == 0
    assert "ok: wall-spoof" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nrules:\n  - {target: {message: DISTANCE_SENSOR, field: colour}, kind: bias, offset: 1}\n")
    assert main(["validate", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert str(bad) in err and "rules[0].target.field" in err and "'colour'" in err


def test_cli_list_show_schema(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(library.names())
    assert any(line.startswith("type-a ") and "reading" in line for line in lines)
    assert main(["show", "type-b"]) == 0
    assert capsys.readouterr().out == library.text("type-b")
    assert main(["show", "type-a", "--param", "links=[13]"]) == 0
    assert json.loads(capsys.readouterr().out)["rules"][0]["target"]["sensor_id"] == [13]
    assert main(["schema"]) == 0
    assert json.loads(capsys.readouterr().out) == profile_json_schema(plugins=True)  # with installed plugins


@pytest.mark.parametrize("argv", [["apply", "type-a", "--vehicle", "1"], ["clear"], ["status"]])
def test_the_library_alone_has_no_live_commands(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """The live subcommands are the proxy's CLI's (mitm_proxy.tools.attack_cli): a usage error here, exit 2."""
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2 and f"invalid choice: '{argv[0]}'" in capsys.readouterr().err


def test_build_parser_lets_the_proxy_plug_in_live_subcommands() -> None:
    seen = []

    def live(sub: Any) -> None:
        p = sub.add_parser("apply")
        p.add_argument("profile")
        p.add_argument("--vehicle", type=int)
        p.set_defaults(func=lambda args: seen.append((args.profile, args.vehicle)) or 0)

    args = build_parser(live).parse_args(["apply", "anchors-ramp", "--vehicle", "2"])
    assert args.func(args) == 0 and seen == [("anchors-ramp", 2)]


def test_every_primitive_module_has_the_same_shape() -> None:
    schema_models = set(json.loads(SCHEMA_PATH.read_text())["$defs"])
    for kind, cls in PRIMITIVES.items():
        if kind not in BUILTIN_KINDS:
            continue  # a plugin's, entered by an earlier test (tests/test_example_plugin.py checks those)
        assert issubclass(cls, Primitive) and issubclass(cls.rule_model, RuleBase)
        assert cls.rule_model.model_fields["kind"].default == kind
        assert cls.__module__ == f"attack_profiles.primitives.{kind}"
        assert cls.rule_model.__doc__ and cls.rule_model.__name__ in schema_models

"""Config file + flags -> ProxyConfig: the port plan, flags over the file, one clear error for bad input."""

from __future__ import annotations

from pathlib import Path

import pytest

from mitm_proxy.cli import build_parser, config_from_args, main
from mitm_proxy.config import ProxyConfig, build_config, load_config
from secuav_common.loading import InputError

REPO = Path(__file__).resolve().parents[2]


def cfg_of(*argv: str) -> ProxyConfig:
    return config_from_args(build_parser().parse_args(list(argv)))


def test_no_flags_is_the_port_plan_for_one_vehicle() -> None:
    cfg = cfg_of()
    assert [(ln.sysid, ln.vehicle, ln.ground) for ln in cfg.links] == [
        (1, "udpin://127.0.0.1:14560", ["udpout://127.0.0.1:14540", "udpout://127.0.0.1:14550"])
    ]
    assert (cfg.attack, cfg.broker, cfg.secure, cfg.record) == ("on", "embedded", "off", None)


def test_vehicles_n_and_scenario_give_one_link_each_sharing_the_gcs_port() -> None:
    cfg = cfg_of("--vehicles", "3")
    assert [ln.vehicle for ln in cfg.links] == [f"udpin://127.0.0.1:{14560 + i}" for i in range(3)]
    assert [ln.ground[0] for ln in cfg.links] == [f"udpout://127.0.0.1:{14540 + i}" for i in range(3)]
    assert {ln.ground[1] for ln in cfg.links} == {"udpout://127.0.0.1:14550"}
    cfg = cfg_of("--scenario", str(REPO / "scenarios/formation.yaml"))
    assert [ln.sysid for ln in cfg.links] == [1, 2]


def test_flags_win_over_the_file(tmp_path: Path) -> None:
    f = tmp_path / "proxy.yaml"
    f.write_text("attack: bypass\nbroker: none\nstats_interval_s: 2\n"
                 "links:\n  - {sysid: 7, vehicle: 'udpin://127.0.0.1:15000', ground: ['udpout://127.0.0.1:15001']}\n")
    cfg = cfg_of("--config", str(f))
    assert (cfg.attack, cfg.broker, cfg.stats_interval_s, cfg.links[0].sysid) == ("bypass", "none", 2.0, 7)
    cfg = cfg_of("--config", str(f), "--attack", "on", "--ground", "udpout://127.0.0.1:15002")
    assert cfg.attack == "on"
    assert cfg.links[0].ground == ["udpout://127.0.0.1:15002"]
    assert cfg.links[0].vehicle == "udpin://127.0.0.1:15000"


def test_vehicle_flag_once_is_offset_per_link_and_link_flag_sets_each() -> None:
    cfg = cfg_of("--vehicles", "2", "--vehicle", "udpin://127.0.0.1:16000")
    assert [ln.vehicle for ln in cfg.links] == ["udpin://127.0.0.1:16000", "udpin://127.0.0.1:16001"]
    cfg = cfg_of("--link", "udpin://127.0.0.1:16000", "udpout://127.0.0.1:16010",
                 "--link", "udpin://127.0.0.1:16001", "udpout://127.0.0.1:16011", "udpout://127.0.0.1:16010")
    assert [(ln.sysid, ln.ground) for ln in cfg.links] == [
        (1, ["udpout://127.0.0.1:16010"]), (2, ["udpout://127.0.0.1:16011", "udpout://127.0.0.1:16010"])]


def test_the_example_config_is_valid() -> None:
    cfg = cfg_of("--config", str(REPO / "examples/proxy.yaml"))
    assert cfg.links


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("attack: maybe\n", "attack"),
        ("broker: amqp://x\n", "broker"),
        ("links:\n  - {sysid: 1, vehicle: 'quic://127.0.0.1:1', ground: ['udpout://127.0.0.1:2']}\n",
         "links[0].vehicle"),
        ("links:\n  - {sysid: 1, vehicle: 'udpin://127.0.0.1:1', ground: ['udpout://127.0.0.1:x']}\n",
         "links[0].ground"),
        ("links:\n  - {sysid: 1, vehicle: 'udpin://127.0.0.1:1', ground: ['udpout://127.0.0.1:2']}\n"
         "  - {sysid: 1, vehicle: 'udpin://127.0.0.1:3', ground: ['udpout://127.0.0.1:2']}\n", "sysid 1"),
        ("stats_interval_s: -1\n", "stats_interval_s"),
        ("colour: blue\n", "colour"),
        ("- just\n- a list\n", "proxy.yaml"),
    ],
)
def test_bad_file_is_one_error_naming_file_field_and_value(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "proxy.yaml"
    f.write_text(text)
    with pytest.raises(InputError) as err:
        cfg_of("--config", str(f))
    message = str(err.value)
    assert message.startswith(str(f)) and needle in message and "\n" not in message


def test_cli_bad_input_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--vehicle", "udpin://127.0.0.1:notaport", "--broker", "none"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "notaport" in err
    assert main(["--profile", str(tmp_path / "missing.yaml"), "--broker", "none"]) == 2
    assert "missing.yaml" in capsys.readouterr().err
    bad = tmp_path / "p.yaml"
    bad.write_text("name: x\nrules:\n  - {target: {message: DISTANCE_SENSOR, field: current_distance}, kind: warp}\n")
    assert main(["--profile", str(bad), "--broker", "none"]) == 2
    assert "p.yaml" in capsys.readouterr().err
    assert main(["--vehicles", "2", "--vehicle", "udpin://127.0.0.1:1", "--vehicle", "udpin://127.0.0.1:2",
                 "--vehicle", "udpin://127.0.0.1:3", "--broker", "none"]) == 2
    assert "once per link (2)" in capsys.readouterr().err


def test_rules_in_the_long_form_are_the_same_rules_as_url_options(tmp_path: Path) -> None:
    from mitm_proxy.net.rules import rules_from_options

    path = tmp_path / "proxy.yaml"
    path.write_text(
        "links:\n"
        "  - sysid: 1\n"
        "    vehicle: udpin://127.0.0.1:14560\n"
        "    ground:\n"
        "      - url: tcpin://127.0.0.1:5760\n"
        "        rules: {listen_only: true, down: {deny: [ATTITUDE]}, up: {allow_sysid: [255]}}\n"
        "      - udpout://127.0.0.1:14550?listen_only=true&deny=ATTITUDE&allow_sysid_up=255\n"
    )
    cfg = build_config(load_config(path), {}, str(path))
    long, short = cfg.links[0].ground_endpoints
    assert rules_from_options(long) == rules_from_options(short)
    assert rules_from_options(long).listen_only and long.port == 5760


@pytest.mark.parametrize(
    ("entry", "needle"),
    [
        ("{url: tcpin://127.0.0.1:5760, rules: {down: {deny: [NOPE]}}}", "[0]: rules.down.deny: 'NOPE' is not"),
        ("{url: tcpin://127.0.0.1:5760, rules: {listen: true}}", "[0]: rules.listen: Extra inputs"),
        ("{url: 'tcpin://127.0.0.1:5760?deny=ATTITUDE', rules: {listen_only: true}}", "not both"),
        ("{url: tcpin://127.0.0.1:5760, rulez: {}}", "rulez"),
    ],
)
def test_a_bad_long_form_names_the_entry_and_the_rule(tmp_path: Path, entry: str, needle: str) -> None:
    path = tmp_path / "proxy.yaml"
    path.write_text(f"links:\n  - sysid: 1\n    vehicle: udpin://127.0.0.1:14560\n    ground:\n      - {entry}\n")
    with pytest.raises(InputError) as err:
        build_config(load_config(path), {}, str(path))
    assert str(path) in str(err.value) and "links[0].ground" in str(err.value) and needle in str(err.value)


def test_print_config_shows_what_would_run_with_the_rules_spelled_out() -> None:
    import subprocess
    import sys

    import yaml

    run = subprocess.run([sys.executable, "-m", "mitm_proxy", "--vehicles", "2", "--print-config", "--ground",
                          "tcpin://127.0.0.1:5760?listen_only=true&deny=ATTITUDE", "--broker-password", "hunter2"],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert run.returncode == 0, run.stderr
    shown = yaml.safe_load(run.stdout)
    assert [ln["sysid"] for ln in shown["links"]] == [1, 2] and shown["broker_password"] == "***"
    ground = shown["links"][0]["ground"][0]
    assert ground == {"url": "tcpin://127.0.0.1:5760", "rules": {"listen_only": True, "down": {"deny": ["ATTITUDE"]}}}
    assert shown["links"][1]["vehicle"] == "udpin://127.0.0.1:14561"

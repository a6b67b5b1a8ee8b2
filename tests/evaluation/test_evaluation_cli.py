"""secuav-eval end to end on short flights: outputs, reproducibility, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import main

FIELDS = {
    "rmse_m",
    "p95_error_m",
    "max_error_m",
    "step_time_us_median",
    "step_time_us_p99",
    "attack_detection_precision",
    "attack_detection_recall",
}
# A secure method's two rows, as a study's tables have them: its own output, and with the shared attribution.
SECURE_ROWS = ("secekf", "secekf+attribution", "rarse", "rarse+attribution")


def _run(out: Path, *extra: str) -> int:
    return main(["--trials", "1", "--duration", "12", "--out", str(out), *extra])


def test_test_case_1_outputs_and_same_seed_same_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ("--scenario", "anchors8", "--attack", "type-a", "--param", "start_s=3", "--estimators", "ekf,secekf,rarse")
    assert _run(tmp_path / "a", *args) == 0
    printed = capsys.readouterr().out
    assert "Mean abs. error [m]" in printed and "Time per step [ms]" in printed
    res = json.loads((tmp_path / "a" / "results.json").read_text())
    assert res["test_case"] == 1 and set(res["estimators"]) == {"ls", "ekf", *SECURE_ROWS}  # ls: baseline
    for row in res["estimators"].values():
        assert set(row) >= FIELDS
    assert {label: row["output"] for label, row in res["estimators"].items()} == {
        "ls": "own", "ekf": "own", "secekf": "own", "secekf+attribution": "attributed", "rarse": "own",
        "rarse+attribution": "attributed",
    }  # fmt: skip
    labels = [line.split(" | ")[0].strip() for line in printed.splitlines()[2:8]]
    assert labels == ["ls", "ekf", *SECURE_ROWS]
    sec, ekf = res["estimators"]["secekf+attribution"], res["estimators"]["ekf"]
    assert sec["rmse_m"] < 0.15 and ekf["rmse_m"] > 2 * sec["rmse_m"]
    assert sec["attack_detection_recall"] >= 0.9 and sec["attack_detection_precision"] >= 0.9
    assert ekf["attack_detection_recall"] == 0.0 and ekf["attack_detection_precision"] is None
    for png in ("attack.png", "errors.png", "trajectory.png"):
        assert (tmp_path / "a" / png).stat().st_size > 1000
    assert _run(tmp_path / "b", *args) == 0
    again = json.loads((tmp_path / "b" / "results.json").read_text())
    for name, row in res["estimators"].items():
        for key in ("rmse_m", "max_error_m", "p95_error_m", "attack_detection_recall"):
            assert again["estimators"][name][key] == row[key], (name, key)


def test_test_case_2_reports_the_inter_vehicle_range(tmp_path: Path) -> None:
    assert _run(tmp_path, "--scenario", "formation", "--attack", "none", "--estimators", "ekf,secopt") == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["test_case"] == 2
    rng = res["estimators"]["secopt+attribution"]["inter_vehicle_range"]
    assert rng["rmse_m"] < 0.3


def test_bad_scenario_names_file_and_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nvehicles:\n  - sysid: 1\n    sensors: {uwb: {noise_std_m: -1}}\n")
    assert _run(tmp_path / "out", "--scenario", str(bad), "--attack", "none") == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "noise_std_m" in err
    assert not (tmp_path / "out").exists()


def test_bad_attack_and_estimator_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(tmp_path / "o1", "--scenario", "anchors8", "--attack", "no-such-profile") == 2
    assert "no-such-profile" in capsys.readouterr().err
    assert _run(tmp_path / "o2", "--scenario", "anchors8", "--attack", "none", "--estimators", "ekf,magic") == 2
    assert "magic" in capsys.readouterr().err
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


def test_wall_hover_group(tmp_path: Path) -> None:
    args = ("--scenario", "wall_hover", "--attack", "wall-spoof-two", "--param", "start_s=2")
    assert _run(tmp_path, *args, "--estimators", "ekf,recap") == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["test_case"] == "wall"
    recap, ekf = res["estimators"]["recap+attribution"], res["estimators"]["ekf"]
    assert recap["max_error_m"] < 0.1 and ekf["max_error_m"] > 0.5
    assert recap["attack_detection_recall"] >= 0.9


def test_moving_leg_type_b_in_parallel_gives_the_serial_numbers(tmp_path: Path) -> None:
    args = ("--scenario", "anchors8", "--attack", "type-b", "--param", "start_s=2", "--param", "rate_per_s=0.5")
    common = (*args, "--leg", "moving", "--trials", "2", "--duration", "10", "--estimators", "ekf,rarse")
    assert main(["--out", str(tmp_path / "par"), "--jobs", "2", *common]) == 0
    assert main(["--out", str(tmp_path / "ser"), "--jobs", "1", *common]) == 0
    par = json.loads((tmp_path / "par" / "results.json").read_text())
    ser = json.loads((tmp_path / "ser" / "results.json").read_text())
    assert par["leg"] == "moving" and par["trials"] == 2
    for name in ("ekf", "rarse", "rarse+attribution"):
        for key in ("rmse_m", "max_error_m", "attack_detection_recall", "attack_detection_precision"):
            assert par["estimators"][name][key] == ser["estimators"][name][key], (name, key)
    rarse, ekf = par["estimators"]["rarse+attribution"], par["estimators"]["ekf"]
    assert rarse["rmse_m"] < 0.12 and ekf["max_error_m"] > 2 * rarse["max_error_m"]
    assert rarse["attack_detection_recall"] >= 0.9


def test_each_formation_vehicle_tolerates_two_of_its_own_anchors(tmp_path: Path) -> None:
    """type-a hits links 11 and 14 of both vehicles: 4 attacked readings of 17, but only two of each vehicle's eight,
    which each vehicle's geometry corrects on its own."""
    args = ("--scenario", "formation", "--attack", "type-a", "--estimators", "ekf,secekf,rarse", "--duration", "8")
    assert main(["--trials", "1", "--out", str(tmp_path), *args]) == 0
    rows = json.loads((tmp_path / "results.json").read_text())["estimators"]
    for name in ("secekf+attribution", "rarse+attribution"):
        assert rows[name]["estimate_fraction"] == 1.0 and rows[name]["rmse_m"] < 0.1, name
    assert rows["ekf"]["rmse_m"] > 0.2  # confidently wrong


def test_over_attacked_formation_alarms_instead_of_guessing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Three of each vehicle's anchor links lie: beyond what either vehicle can correct."""
    args = ("--scenario", "formation", "--attack", "anchors-overwhelm", "--estimators", "ekf,secekf", "--duration", "8")
    params = ("--param", "links=[10,11,12]", "--param", "start_s=0")
    assert main(["--trials", "1", "--out", str(tmp_path), *args, *params]) == 0
    assert "refuses to guess" in capsys.readouterr().out
    rows = json.loads((tmp_path / "results.json").read_text())["estimators"]
    sec = rows["secekf+attribution"]
    assert sec["alarm_fraction"] == 1.0 and sec["estimate_fraction"] == 0.0
    assert sec["rmse_m"] is None
    assert rows["ekf"]["estimate_fraction"] == 1.0 and rows["ekf"]["rmse_m"] > 0.2  # confidently wrong


def test_the_height_is_inside_the_attack_surface_offline() -> None:
    """height-spoof ramps the downward laser. The laser is a reading of test case 1's model, so the attack
    reaches it (its offset is scored), the secure estimator outvotes and names it, and the error stays at the
    clean level (in the 2-D model, which takes the laser's height as known, it cost 0.2-1 m)."""
    from attack_profiles import library
    from estimators.models import AnchorRangesHeight
    from estimators.scenario_models import anchor_model
    from evaluation.trial import run_trial
    from secuav_common.scenario import load_scenario

    scenario = load_scenario("anchors8")
    model = anchor_model(scenario)
    assert isinstance(model, AnchorRangesHeight) and model.ids()[-1] == 0  # the laser, DISTANCE_SENSOR id 0
    spoof = library.load("height-spoof", rate_per_s=0.3)
    clean = run_trial(scenario, None, ["secekf", "ekf"], 3, 15.0, "hover")
    spoofed = run_trial(scenario, spoof, ["secekf", "ekf"], 3, 15.0, "hover")
    late = clean.t_s > 10.0
    laser = model.p - 1
    assert np.all(spoofed.offsets_m[late, laser] > 1.0) and np.all(spoofed.offsets_m[late, :laser] == 0.0)
    sec = spoofed.traces["secekf"]
    assert sec.named[late, laser].mean() > 0.9 and not sec.named[late, :laser].any()
    assert np.nanmean(sec.err_m[late]) < 1.5 * np.nanmean(clean.traces["secekf"].err_m[late])
    # The height itself: held by the ranges, while the undefended EKF follows the spoofed laser.
    assert sec.height_err_m is not None and np.sqrt(np.nanmean(sec.height_err_m[late] ** 2)) < 0.15
    ekf = spoofed.traces["ekf"].height_err_m
    assert ekf is not None and np.nanmean(ekf[late]) > 1.0


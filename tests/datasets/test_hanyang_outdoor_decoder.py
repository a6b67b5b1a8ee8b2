"""The Hanyang outdoor UWB decoder on a real 30 s excerpt of one LOS and one NLOS run (tests/data/hanyang_uwb,
Apache-2.0): it decodes four asynchronous anchor files and the RTK reference, finds the clock lag and tag height it
documents, drops reference glitches, names bad lines, and its output runs through ``secuav-eval --ranges``."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import main as eval_main

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "datasets" / "hanyang_outdoor_uwb.py"
EXCERPT = ROOT / "tests" / "data" / "hanyang_uwb"
RUNS = [("LOS", 4), ("NLOS", 3)]


def _load():
    spec = importlib.util.spec_from_file_location("hanyang_outdoor_uwb", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["hanyang_outdoor_uwb"] = mod
    spec.loader.exec_module(mod)
    return mod


hy = _load()


@pytest.mark.parametrize(("env", "case"), RUNS)
def test_decodes_four_asynchronous_anchors_and_the_reference(env: str, case: int) -> None:
    run = hy.read_run(EXCERPT, env, case)
    assert [a.anchor_id for a in run.anchors] == [3, 5, 9, 12]
    assert all(a.t_s.size == 300 and 8.0 < 1.0 / np.median(np.diff(a.t_s)) < 12.0 for a in run.anchors)
    assert min(a.t_s[0] for a in run.anchors) == 0.0
    # each anchor on its own stamps: no two links share one
    stamps = np.concatenate([a.t_s for a in run.anchors])
    assert np.unique(stamps).size == stamps.size
    assert run.t_ref_s.size == 240 and run.kept.all()
    errors = np.concatenate(hy.range_errors(run))
    assert np.nanmedian(np.abs(errors)) < 0.3  # the frame, anchors and truth agree to decimetres


@pytest.mark.parametrize(("env", "case"), RUNS)
def test_the_documented_lag_and_tag_height_fit_best(env: str, case: int) -> None:
    # The ranges are stamped late against the reference: 0.2 s over whole runs, 0.1 s in these first 30 s.
    run = hy.read_run(EXCERPT, env, case)
    spread = {lag: hy._spread(hy.range_errors(run, "fixed", lag))[1] for lag in (0.0, 0.1, 0.2, 0.3)}
    best = hy.best_lag_s(run, np.array(sorted(spread)))
    assert best in (0.1, 0.2) and spread[best] < 0.85 * spread[0.0]
    # the tag rides 1 m above the reference, not at its height
    at_lag = spread[hy.CLOCK_LAG_S]
    assert at_lag < 0.7 * hy._spread(hy.range_errors(run, "reference"))[1]


def test_reference_glitches_are_dropped_and_a_real_track_kept() -> None:
    t = np.arange(0.0, 10.0, 0.125)
    xyz = np.column_stack([1.0 * t, np.zeros_like(t), np.zeros_like(t)])  # 1 m/s along x
    assert hy.glitch_free(t, xyz).all()
    spiked = xyz.copy()
    spiked[20, 0] += 40.0  # one fix 40 m off
    spiked[50, 2] = 1.6  # one fix 1.6 m up
    kept = hy.glitch_free(t, spiked)
    assert list(np.flatnonzero(~kept)) == [20, 50]


def _copy_run(tmp_path: Path, env: str, case: int) -> Path:
    src = hy.case_dir(EXCERPT, env, case)
    dst = hy.case_dir(tmp_path, env, case)
    dst.mkdir(parents=True)
    for f in src.iterdir():
        (dst / f.name).write_bytes(f.read_bytes())
    return dst


@pytest.mark.parametrize(
    ("name", "edit", "message"),
    [
        ("A9.csv", lambda rows: rows.__setitem__(4, rows[4].replace(",", ",x", 1)), r"A9.csv: line 5: stamp 'x"),
        ("A5.csv", lambda rows: rows.__setitem__(7, rows[7].rsplit(",", 3)[0] + ",y,1,2"), r"line 8: value 'y'"),
        ("A3.csv", lambda rows: rows.__setitem__(9, rows[9].replace(",2.21,", ",2.5,", 1)), r"line 10: anchor posit"),
        ("trajectory.csv", lambda rows: rows.__setitem__(0, rows[0].replace("timestamp", "t")), r"no column"),
    ],
)
def test_a_bad_line_is_named(tmp_path: Path, name: str, edit, message: str) -> None:
    path = _copy_run(tmp_path, "NLOS", 3) / name
    rows = path.read_text().splitlines()
    edit(rows)
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(hy.DatasetError, match=message):
        hy.read_run(tmp_path, "NLOS", 3)
    assert hy.main(["fit", "--source", str(tmp_path), "--cases", "NLOS:3"]) == 2


def test_fit_prints_the_noise_of_both_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert hy.main(["fit", "--source", str(EXCERPT), "--cases", "LOS:4,NLOS:3"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["commit"] == hy.COMMIT and result["licence"] == "Apache-2.0" and result["links"] == 8
    assert 0.03 < result["sigma_m"]["median"] < 0.3
    assert set(result["runs"]) == {"LOS/Trajectory_B/Case_4", "NLOS/Trajectory_B/Case_3"}


@pytest.mark.parametrize(("env", "case"), RUNS)
def test_converted_run_goes_through_secuav_eval(tmp_path: Path, env: str, case: int) -> None:
    out = tmp_path / "rec"
    assert hy.main(["convert", "--source", str(EXCERPT), "--env", env, "--case", str(case), "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "ranges.csv").open()))
    assert len(rows) == 1200 and {r["sensor_id"] for r in rows} == {"10", "11", "12", "13"}
    assert [float(r["t_s"]) for r in rows] == sorted(float(r["t_s"]) for r in rows)
    text = (out / "scenario.yaml").read_text()
    assert hy.COMMIT in text and "Apache-2.0" in text and "area:" in text

    def evaluate(scenario: Path, name: str) -> dict:
        argv = ["--scenario", str(scenario), "--ranges", str(out / "ranges.csv"), "--truth", str(out / "truth.csv"),
                "--dims", "2", "--rate", "10", "--attack", "none", "--estimators", "ls,ekf",
                "--out", str(tmp_path / name)]  # fmt: skip
        assert eval_main(argv) == 0
        return json.loads((tmp_path / name / "results.json").read_text())

    res = evaluate(out / "scenario.yaml", "eval")
    assert res["errors_scored"]
    for name in ("ls", "ekf"):
        est = res["estimators"][name]
        assert est["estimate_fraction"] > 0.9
        assert est["mean_error_m"] < 1.0 and est["rmse_m"] < 2.0  # measured 0.4-0.8 / 0.9-1.6 m
    # Without the stated area the fixes are clipped to the anchors' box while the tag drives 1.5-23 m out.
    boxed = out / "boxed.yaml"
    boxed.write_text("\n".join(line for line in text.splitlines() if "area:" not in line) + "\n")
    assert evaluate(boxed, "boxed")["estimators"]["ls"]["mean_error_m"] > 2 * res["estimators"]["ls"]["mean_error_m"]

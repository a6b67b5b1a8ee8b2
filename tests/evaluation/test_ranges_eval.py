"""secuav-eval --ranges: recorded ranges in the documented CSV (docs/recorded-ranges.md), with truth,
clean and with an attack injected by the attack_profiles engine; the false-alarm figures of the report."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import main
from evaluation.ranges import read_ranges_csv
from evaluation.report import false_alarms
from evaluation.trial import EstimatorTrace, TrialResult
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario

RATE_HZ = 20.0
SECONDS = 30.0
SIGMA = 0.1  # anchors8's stated UWB noise


def _path(t: np.ndarray) -> np.ndarray:
    """A slow circle of 1 m radius about anchors8's centre at its hold height."""
    return np.column_stack([2.5 + np.cos(0.2 * t), 2.5 + np.sin(0.2 * t), np.full(t.shape, -2.5)])


def _write_recording(folder: Path, with_sysid: bool = True, bad_rows: int = 0) -> tuple[Path, Path]:
    scenario = load_scenario("anchors8")
    anchors = scenario.anchor_positions()
    rng = np.random.default_rng(7)
    t = np.arange(0.0, SECONDS, 1.0 / RATE_HZ)
    pos = _path(t)
    ranges = folder / "ranges.csv"
    with ranges.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "sensor_id", "range_m"] if with_sysid else ["range_m", "sensor_id", "t_s"])
        for k, tk in enumerate(t):
            for a in sorted(anchors):
                value = float(np.linalg.norm(pos[k] - np.array(anchors[a]))) + rng.normal(0.0, SIGMA)
                cell = "" if (k % 50 == 3 and a == 2) else f"{value:.3f}"
                w.writerow([f"{tk:.3f}", 1, 10 + a, cell] if with_sysid else [cell, 10 + a, f"{tk:.3f}"])
        for _ in range(bad_rows):
            w.writerow(["soon", 1, 10, "3.0"] if with_sysid else ["3.0", 10, "soon"])
    truth = folder / "truth.csv"
    with truth.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, p in zip(t, pos, strict=True):
            w.writerow([f"{tk:.3f}", 1, *(f"{v:.4f}" for v in p)])
    return ranges, truth


def test_reader_keeps_missing_readings_and_counts_bad_rows(tmp_path: Path) -> None:
    ranges, _ = _write_recording(tmp_path, with_sysid=False, bad_rows=3)
    logs, info, skipped = read_ranges_csv(ranges, default_sysid=1)
    assert skipped == 3 and info.sysids == (1,) and info.sensor_ids[1] == tuple(range(10, 18))
    rows = logs[1].readings[12]
    assert len(rows) == SECONDS * RATE_HZ and sum(math.isnan(v) for _, v in rows) == 12  # every 50th frame
    assert info.invalid_readings == 12


def test_reader_refuses_a_file_without_its_columns(tmp_path: Path) -> None:
    bad = tmp_path / "r.csv"
    bad.write_text("time,id,value\n0,10,3.0\n")
    with pytest.raises(InputError, match=r"r\.csv.*t_s.*missing column"):
        read_ranges_csv(bad, 1)
    bad.write_text("t_s,sensor_id,range_m\nx,10,3.0\n")
    with pytest.raises(InputError, match="no readable row"):
        read_ranges_csv(bad, 1)


def _run(tmp_path: Path, attack: str, capsys: pytest.CaptureFixture[str]) -> dict:
    ranges, truth = _write_recording(tmp_path, bad_rows=2)
    out = tmp_path / attack
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2"]
    assert main([*argv, "--estimators", "ekf,secekf", "--attack", attack, "--rate", "10", "--out", str(out)]) == 0
    assert "False alarms /h" in capsys.readouterr().out
    return json.loads((out / "results.json").read_text())


def test_clean_recording_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    res = _run(tmp_path, "none", capsys)
    assert res["source"] == "ranges" and res["log"]["rows_skipped"] == 2 and res["errors_scored"]
    assert res["rate_hz"] == 10.0 and res["frames"] == SECONDS * 10
    ekf = res["estimators"]["ekf"]
    assert ekf["rmse_m"] < 0.15  # white noise of the stated sigma: the EKF tracks the circle
    sec = res["estimators"]["secekf+attribution"]
    assert sec["attack_free_hours"] == pytest.approx((SECONDS - 1.0) / 3600, rel=0.02)  # all but the warm-up
    for key in ("false_alarm_per_step", "false_alarms_per_run", "false_alarms_per_hour", "false_accusations_per_hour"):
        assert sec[key] is not None and sec[key] >= 0


def test_attack_injected_on_recorded_ranges(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    res = _run(tmp_path, "anchors-constant", capsys)  # links 11 and 14 +1.5 m from 5 s
    sec, ekf = res["estimators"]["secekf+attribution"], res["estimators"]["ekf"]
    named = sec["named_fraction_by_sensor_id"]
    assert named["11"] > 0.5 and named["14"] > 0.5 and max(named[k] for k in named if k not in ("11", "14")) < 0.2
    assert sec["rmse_m"] < ekf["rmse_m"]
    assert sec["attack_free_hours"] == pytest.approx(4.0 / 3600, rel=0.05)  # 1..5 s: before the onset


def test_tlog_and_ranges_are_exclusive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges, _ = _write_recording(tmp_path)
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--tlog", str(ranges), "--out", str(tmp_path / "o")]
    assert main(argv) == 2 and "one recording" in capsys.readouterr().err


def _trial(alarm: np.ndarray, named: np.ndarray, added: np.ndarray) -> TrialResult:
    n, p = named.shape
    t = np.arange(1, n + 1) / 10.0
    trace = EstimatorTrace(np.zeros(n), None, np.zeros((n, 2)), np.zeros(n), named, alarm)
    zeros = np.zeros((n, p))
    return TrialResult(t, np.zeros((n, 2)), np.zeros((0, 2)), zeros, np.full(p, 0.1), tuple(range(p)),
                       {"x": trace}, added_m=added)  # fmt: skip


def test_false_alarm_figures_count_events_on_untouched_steps() -> None:
    n, p = 36010, 3  # one hour after the 1 s warm-up at 10 Hz
    alarm = np.zeros(n, dtype=bool)
    named = np.zeros((n, p), dtype=bool)
    added = np.zeros((n, p))
    alarm[100:103] = True  # one event of three steps
    alarm[5000] = True  # a second event
    added[20000:, 0] = 1.5  # attacked from here: alarms there are not false
    alarm[25000:25010] = True
    named[25000:25010, 0] = True  # rightly named
    named[30000, 1] = True  # an honest link named under attack: a false accusation
    fa = false_alarms([_trial(alarm, named, added)], "x")
    assert fa["false_alarms_per_run"] == 2 and fa["false_accusations_per_run"] == 1
    quiet_h = (20000 - 10) / 10 / 3600
    assert fa["false_alarms_per_hour"] == pytest.approx(2 / quiet_h)
    assert fa["false_alarm_per_step"] == pytest.approx(4 / (20000 - 10))
    assert fa["false_accusations_per_hour"] == pytest.approx(1.0)


def test_calibration_flags_reach_the_estimators_and_the_scoring(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ranges, truth = _write_recording(tmp_path)
    out = tmp_path / "cal"
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2", "--rate", "10"]
    argv += ["--estimators", "ekf,secekf", "--attack", "none", "--calibrate", "5", "--tail-dof", "6.2"]
    assert main([*argv, "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["calibration_s"] == 5.0 and res["calibration_tail_dof"] == 6.2 and res["score_from_s"] == 6.0
    sec = res["estimators"]["secekf+attribution"]
    assert sec["attack_free_hours"] == pytest.approx((SECONDS - 6.0) / 3600, rel=0.02)
    assert sec["false_accusation_per_step"] < 0.02  # white noise of the stated sigma, widened for the tails
    assert main([*argv[:-4], "--tail-dof", "6.2", "--out", str(tmp_path / "x")]) == 2
    assert "--tail-dof" in capsys.readouterr().err

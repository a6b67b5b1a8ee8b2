"""Baselines in every table (issue 34, item 3): the undefended snapshot least-squares fix (``ls``) and the EKF
appear in every table the evaluation and the study produce, and a secure method that loses to least squares on
clean data says so."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import pytest

from evaluation.cli import main
from evaluation.report import compare_with_ls, table
from study import store
from study.suite.run import leaderboard, markdown
from tests.support.recorded import write_ranges


def _row(rmse: float) -> dict:
    return {"rmse_m": rmse, "mean_error_m": rmse, "max_error_m": 2 * rmse, "step_time_us_median": 10.0,
            "step_time_us_p99": 20.0, "false_alarms_per_hour": 0.0, "false_accusations_per_hour": 0.0}  # fmt: skip


def test_a_secure_method_worse_than_least_squares_on_clean_data_is_marked() -> None:
    summary = {"ls": _row(0.10), "ekf": _row(0.12), "secekf": _row(0.15), "recap": _row(0.08)}
    compare_with_ls(summary, clean=True)
    assert summary["secekf"]["rmse_vs_ls"] == pytest.approx(1.5) and summary["secekf"]["loses_to_ls_clean"]
    assert not summary["recap"]["loses_to_ls_clean"]
    assert not summary["ekf"]["loses_to_ls_clean"]  # undefended: a baseline, not a secure method
    text = table(summary)
    assert "secekf*" in text and "recap*" not in text and "RMSE / LS" in text
    assert "* loses to the undefended least-squares fix on this clean run: secekf (1.50x)." in text
    attacked = {"ls": _row(0.5), "secekf": _row(0.6)}
    compare_with_ls(attacked, clean=False)
    assert attacked["secekf"]["loses_to_ls_clean"] is None and "secekf*" not in table(attacked)


def test_the_evaluation_adds_the_baselines_it_was_not_given(tmp_path: Path) -> None:
    ranges, truth = write_ranges(tmp_path, 20.0, 10.0, round_robin=False)
    out = tmp_path / "o"
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2",
            "--estimators", "secekf", "--attack", "none", "--rate", "10", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    res = json.loads((out / "results.json").read_text())["estimators"]
    assert list(res) == ["ls", "ekf", "secekf", "secekf+attribution"]  # a secure method's two rows
    assert res["ls"]["rmse_vs_ls"] == pytest.approx(1.0)
    for label in ("secekf", "secekf+attribution"):
        secekf = res[label]
        assert secekf["loses_to_ls_clean"] == (secekf["rmse_vs_ls"] > 1.0)
    lines = (out / "table.txt").read_text().splitlines()
    assert any(line.startswith("ls ") for line in lines) and any(line.startswith("ekf ") for line in lines)


def _rows(estimator: str, attack: str, rmse: float, cell: str) -> dict:
    return {"study": "tc1", "cell": cell, "scenario": "anchors8", "mode": "offline", "leg": "hover",
            "attack": attack, "params": None, "seed": 0, "estimator": estimator, "estimator_name": estimator,
            "estimator_dist": "secuav", "estimator_version": "0", "status": "ok", "rmse_m": rmse,
            "valid_fraction": 1.0, "false_alarm_rate": 0.0, "wall_s": 1.0, "step_time_us_median": 5.0,
            "started_at": datetime(2026, 1, 1, tzinfo=UTC)}  # fmt: skip


def test_the_leaderboard_compares_every_method_with_least_squares_on_clean_runs(tmp_path: Path) -> None:
    (tmp_path / "suite.json").write_text(json.dumps({"suite": "1", "variant": "quick"}))
    rows = [_rows("ls", "none", 0.10, "c0"), _rows("secekf", "none", 0.13, "c0"), _rows("recap", "none", 0.09, "c0"),
            _rows("ls", "relay", 0.90, "c1"), _rows("secekf", "relay", 0.20, "c1"),
            _rows("recap", "relay", 0.25, "c1")]  # fmt: skip
    store.Writer(tmp_path / "tc1").write(rows)
    board, prov = leaderboard(tmp_path)
    by = board.set_index("method")
    assert by.loc["secekf", "clean_vs_ls"] == pytest.approx(1.3) and by.loc["secekf", "worse_than_ls"]
    assert by.loc["recap", "clean_vs_ls"] == pytest.approx(0.9) and not by.loc["recap", "worse_than_ls"]
    text = markdown(board, prov)
    assert "clean RMSE / LS" in text and "| 1.30 **worse than LS** |" in text and "| 0.90 |" in text

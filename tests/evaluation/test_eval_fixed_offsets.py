"""secuav-eval --calibrate follows the offsets by default and says so in results.json; --fixed-offsets keeps the
window's and needs --calibrate (docs/recorded-ranges.md, "After the window")."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import main
from secuav_common.scenario import load_scenario

RATE_HZ = 10.0
SECONDS = 30.0


def _recording(folder: Path) -> tuple[Path, Path]:
    """anchors8 ranges along a slow circle, white noise of the stated 0.1 m, links reading 0.2 m long."""
    anchors = load_scenario("anchors8").anchor_positions()
    rng = np.random.default_rng(3)
    t = np.arange(0.0, SECONDS, 1.0 / RATE_HZ)
    pos = np.column_stack([2.5 + np.cos(0.2 * t), 2.5 + np.sin(0.2 * t), np.full(t.shape, -2.5)])
    ranges, truth = folder / "ranges.csv", folder / "truth.csv"
    with ranges.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "sensor_id", "range_m"])
        for k, tk in enumerate(t):
            for a in sorted(anchors):
                value = float(np.linalg.norm(pos[k] - np.array(anchors[a]))) + 0.2 + rng.normal(0.0, 0.1)
                w.writerow([f"{tk:.3f}", 1, 10 + a, f"{value:.3f}"])
    with truth.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, p in zip(t, pos, strict=True):
            w.writerow([f"{tk:.3f}", 1, *(f"{v:.4f}" for v in p)])
    return ranges, truth


def test_tracking_is_the_default_and_fixed_offsets_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ranges, truth = _recording(tmp_path)
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2", "--rate", "10"]
    argv += ["--estimators", "ekf,secekf", "--attack", "none"]
    for flag, tracked in (([], True), (["--fixed-offsets"], False)):
        out = tmp_path / f"run-{tracked}"
        assert main([*argv, "--calibrate", "5", *flag, "--out", str(out)]) == 0
        res = json.loads((out / "results.json").read_text())
        assert res["calibration_track"] is tracked
        cal = res["estimators"]["secekf"]["calibration"][0]
        assert (cal["tracking"] is not None) is tracked
        assert all(("drift_m" in link) is tracked for link in cal["links"].values())
        # ls and ekf name nothing, so nothing is followed for them
        assert res["estimators"]["ekf"]["calibration"][0]["tracking"] is None
    assert main([*argv, "--fixed-offsets", "--out", str(tmp_path / "x")]) == 2
    assert "--fixed-offsets" in capsys.readouterr().err

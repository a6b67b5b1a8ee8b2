"""``secuav-eval --async`` (issue 34, item 1's first step): on recorded ranges the EKF takes every reading at its
own time (sequential updates), its output predicted to each frame time; the other estimators stay framed."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from evaluation.cli import main
from secuav_common.scenario import load_scenario

SIGMA = 0.1


def _write(folder: Path, seconds: float, poll_hz: float) -> tuple[Path, Path]:
    """A tag that polls anchors8's eight anchors one at a time (each link at poll_hz / 8) while it circles at
    0.3 m/s: no two readings share a timestamp, and a frame's readings are up to a frame old."""
    anchors = load_scenario("anchors8").anchor_positions()
    rng = np.random.default_rng(11)
    t = np.arange(0.0, seconds, 1.0 / poll_hz)
    pos = np.column_stack([2.5 + 1.5 * np.cos(0.2 * t), 2.5 + 1.5 * np.sin(0.2 * t), np.full(t.shape, -2.5)])
    ranges, truth = folder / "ranges.csv", folder / "truth.csv"
    with ranges.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sensor_id", "range_m"])
        for k, tk in enumerate(t):
            a = k % 8
            w.writerow([f"{tk:.4f}", 10 + a, f"{np.linalg.norm(pos[k] - anchors[a]) + rng.normal(0, SIGMA):.4f}"])
    with truth.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, p in zip(t, pos, strict=True):
            w.writerow([f"{tk:.4f}", 1, *(f"{v:.4f}" for v in p)])
    return ranges, truth


def _eval(ranges: Path, truth: Path, out: Path, *extra: str) -> dict:
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2",
            "--estimators", "ls,ekf,secekf", "--rate", "1", "--out", str(out), *extra]  # fmt: skip
    assert main(argv) == 0
    return json.loads((out / "results.json").read_text())


def test_the_ekf_reads_each_reading_at_its_own_time(tmp_path: Path) -> None:
    ranges, truth = _write(tmp_path, 60.0, 16.0)
    sync = _eval(ranges, truth, tmp_path / "sync", "--attack", "none")
    both = _eval(ranges, truth, tmp_path / "async", "--attack", "none", "--async")
    assert both["processing"] == {"ls": "synchronous", "ekf": "asynchronous", "secekf": "synchronous"}
    assert sync["processing"]["ekf"] == "synchronous"
    # The framed estimators see the same frames either way: identical figures.
    assert both["estimators"]["ls"]["rmse_m"] == sync["estimators"]["ls"]["rmse_m"]
    assert both["estimators"]["secekf"]["rmse_m"] == sync["estimators"]["secekf"]["rmse_m"]
    ekf = both["estimators"]["ekf"]
    assert ekf["estimate_fraction"] == 1.0 and ekf["rmse_m"] < 0.2  # started from a frame, then reading by reading
    # Framed at 1 Hz a frame holds readings up to 1 s (0.3 m of motion) old; read at their times they are not.
    assert ekf["rmse_m"] < 0.9 * sync["estimators"]["ekf"]["rmse_m"]
    # An attack injected here reaches the readings the EKF takes one at a time: +1.5 m on links 11 and 14.
    attacked = _eval(ranges, truth, tmp_path / "a", "--attack", "anchors-constant", "--async")
    assert attacked["estimators"]["ekf"]["rmse_m"] > ekf["rmse_m"] + 0.2


def test_async_is_for_recorded_ranges_only(tmp_path: Path) -> None:
    argv = ["--scenario", "anchors8", "--attack", "none", "--async", "--out", str(tmp_path / "o")]
    assert main(argv) == 2

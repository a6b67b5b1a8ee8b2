"""Asynchronous processing of recorded ranges (issue 34, item 1; the default of ``secuav-eval --ranges``): the EKF
takes every reading at its own time (sequential updates), the other estimators a window of readings brought to each
output time with the motion model (estimators.aligned); ``--sync`` frames them as before."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evaluation.cli import main
from tests.support.recorded import write_polled

SIGMA = 0.1


def _write(folder: Path, seconds: float, poll_hz: float) -> tuple[Path, Path]:
    """A tag that polls anchors8's eight anchors one at a time (each link at poll_hz / 8) while it circles at
    0.3 m/s: no two readings share a timestamp, and a frame's readings are up to a frame old."""
    t = np.arange(0.0, seconds, 1.0 / poll_hz)
    pos = np.column_stack([2.5 + 1.5 * np.cos(0.2 * t), 2.5 + 1.5 * np.sin(0.2 * t), np.full(t.shape, -2.5)])
    return write_polled(folder, t, pos, SIGMA, seed=11)


def _eval(ranges: Path, truth: Path, out: Path, *extra: str) -> dict:
    argv = ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2",
            "--estimators", "ls,ekf,secekf", "--rate", "1", "--out", str(out), *extra]  # fmt: skip
    assert main(argv) == 0
    return json.loads((out / "results.json").read_text())


def test_every_estimator_reads_each_reading_at_its_own_time(tmp_path: Path) -> None:
    ranges, truth = _write(tmp_path, 60.0, 16.0)
    sync = _eval(ranges, truth, tmp_path / "sync", "--attack", "none", "--sync")
    both = _eval(ranges, truth, tmp_path / "async", "--attack", "none")  # the default on recorded ranges
    assert both["processing"] == {
        "ls": "aligned", "ekf": "sequential", "secekf": "aligned", "secekf+attribution": "aligned"}
    assert both["async_window_s"] == 1.0 and sync["async_window_s"] is None
    assert set(sync["processing"].values()) == {"synchronous"}
    for name in ("ls", "ekf", "secekf+attribution"):  # the rows read before secure methods had two
        got, framed = both["estimators"][name], sync["estimators"][name]
        assert got["estimate_fraction"] == 1.0
        # Framed at 1 Hz a frame holds readings up to 1 s (0.3 m of motion) old; brought to the frame's time (or
        # read at their own times, the EKF) they are not.
        assert got["rmse_m"] < 0.9 * framed["rmse_m"], name
    assert both["estimators"]["ekf"]["rmse_m"] < 0.2
    # An attack injected here reaches the readings taken one at a time: +1.5 m on links 11 and 14.
    attacked = _eval(ranges, truth, tmp_path / "a", "--attack", "anchors-constant")
    assert attacked["estimators"]["ekf"]["rmse_m"] > both["estimators"]["ekf"]["rmse_m"] + 0.2
    sec = attacked["estimators"]["secekf+attribution"]
    assert sec["attack_detection_recall"] > 0.9 and sec["rmse_m"] < 0.2


def test_async_is_for_recorded_ranges_only(tmp_path: Path) -> None:
    argv = ["--scenario", "anchors8", "--attack", "none", "--async", "--out", str(tmp_path / "o")]
    assert main(argv) == 2

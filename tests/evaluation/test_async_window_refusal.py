"""``secuav-eval`` on recorded ranges processes them asynchronously by default (issue 34, item 1): a window too short
for the links' rates is refused in one line naming each link and its numbers, never run half empty."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import main
from tests.support.recorded import write_polled


def _write(folder: Path, seconds: float, poll_hz: float) -> tuple[Path, Path]:
    """A tag polling anchors8's anchors one at a time (each link at poll_hz / 8), hovering with 0.05 m noise."""
    t = np.arange(0.0, seconds, 1.0 / poll_hz)
    return write_polled(folder, t, np.tile([2.0, 3.0, -2.5], (t.size, 1)), 0.05, seed=2, t_format=".3f")


def _argv(ranges: Path, truth: Path, out: Path, *extra: str) -> list[str]:
    return ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2",
            "--estimators", "ekf,secekf", "--attack", "none", "--out", str(out), *extra]  # fmt: skip


def test_a_window_shorter_than_the_links_need_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges, truth = _write(tmp_path, 40.0, 4.0)  # each link every 2 s
    out = tmp_path / "o"
    assert main(_argv(ranges, truth, out, "--rate", "4")) == 2  # the window defaults to one period: 0.25 s
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "ranges.csv: --window" in err
    assert "asynchronous window 0.25 s at 4 Hz: 8 link(s) read too seldom" in err
    assert "10: 0.50/s in 12%" in err and "17: 0.50/s in 12%" in err and "give a window of 2 s or more" in err
    assert not out.exists()
    # A window that holds every link's latest reading: it runs, each reading brought to the output's time.
    assert main(_argv(ranges, truth, out, "--rate", "4", "--window", "2.5")) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["async_window_s"] == 2.5 and res["processing"]["secekf"] == "aligned"
    assert res["estimators"]["secekf+attribution"]["rmse_m"] < 0.1 and res["estimators"]["ekf"]["rmse_m"] < 0.1


def test_window_needs_asynchronous_processing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges, truth = _write(tmp_path, 10.0, 8.0)
    assert main(_argv(ranges, truth, tmp_path / "o", "--sync", "--window", "1")) == 2
    assert "--window" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # one or the other
        main(_argv(ranges, truth, tmp_path / "o", "--sync", "--async"))

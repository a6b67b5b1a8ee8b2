"""Calibration that says what it did (issue 34, item 5): ``--calibrate S`` on recorded ranges and the study option
count each link's readings in the window, then either calibrate (results.json: per link the readings used, the
offset and the scale) or refuse with one line naming each link's count and what it needs; a recording too sparse
for the framing rate is refused the same way. Never a silent no-op."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from estimators import noise
from estimators.scenario_models import anchor_model
from evaluation.cli import main
from secuav_common.scenario import load_scenario
from tests.support.recorded import OFFSETS, SIGMA, path_at, write_ranges


def _argv(ranges: Path, truth: Path, out: Path, *extra: str) -> list[str]:
    return ["--scenario", "anchors8", "--ranges", str(ranges), "--truth", str(truth), "--dims", "2",
            "--estimators", "ekf,secekf", "--attack", "none", "--out", str(out), *extra]  # fmt: skip


def test_window_count_names_every_link_and_what_it_needs() -> None:
    model = anchor_model(load_scenario("anchors8"), dims=2)
    t = np.arange(0.0, 30.0, 1.0)
    z = np.full((t.size, model.p), 3.0)
    z[::2, 0] = np.nan  # link 10 read every other second
    count = noise.count_window(model, t, z, 20.0)
    assert (count.steps, count.fixes) == (21, 21) and count.reading_counts[0] == 10 and count.reading_counts[1] == 21
    line = count.refusal(model.ids())
    assert line is not None and "\n" not in line
    assert "21 of 21 steps have a fix (needs 20)" in line and "10: 10, 11: 21" in line and "17: 21" in line
    assert f"each link needs {noise.MIN_LINK_READINGS}; short: 10)" in line
    full = noise.count_window(model, t, np.full((t.size, model.p), 3.0), 20.0)
    assert full.refusal(model.ids()) is None
    short = noise.count_window(model, t[:10], z[:10], 20.0)
    assert "readings end after 9.0 s" in (short.refusal(model.ids()) or "")


def test_calibrated_reports_offsets_scales_and_readings_or_why_not() -> None:
    model = anchor_model(load_scenario("anchors8"), dims=2)
    rng = np.random.default_rng(0)

    def feed(est: noise.Calibrated, steps: int, every: int) -> None:
        for k in range(steps):
            pos = path_at(np.array([0.1 * k]))[0]
            z = model.h(pos[:2], pos[2]) + OFFSETS + rng.normal(0.0, SIGMA, model.p)
            if k % every:
                z[0] = np.nan
            est.step(0.1 * k, z, pos[2])

    done = noise.create("ekf", model, calibration_s=5.0)
    assert isinstance(done, noise.Calibrated)
    feed(done, 80, 1)
    rep = done.report()
    assert rep["status"] == "calibrated" and rep["steps_with_fix"] == 51
    assert set(rep["links"]) == {str(i) for i in range(10, 18)}
    assert all(v["readings"] == 51 for v in rep["links"].values())
    # The offsets that a shift of the position cannot explain come out: their spread, not their mean.
    got = np.array([v["offset_m"] for v in rep["links"].values()])
    assert np.std(got - OFFSETS) < 0.05 and all(v["sigma_m"] > 0 for v in rep["links"].values())

    refused = noise.create("ekf", model, calibration_s=5.0)
    assert isinstance(refused, noise.Calibrated)
    feed(refused, 80, 4)  # link 10 in one step of four: 13 readings in the window
    rep = refused.report()
    assert rep["status"] == "refused" and refused.calibration is None
    assert rep["links"]["10"] == {"readings": 13} and "short: 10)" in rep["reason"]

    unfinished = noise.create("ekf", model, calibration_s=50.0)
    assert isinstance(unfinished, noise.Calibrated)
    feed(unfinished, 20, 1)
    assert unfinished.report()["status"] == "incomplete"


def test_eval_refuses_a_window_too_sparse_to_calibrate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's case: a window of 8 framed steps silently did nothing while results.json said it calibrated."""
    ranges, truth = write_ranges(tmp_path, 60.0, 2.0, round_robin=False)
    out = tmp_path / "o"
    assert main(_argv(ranges, truth, out, "--rate", "0.4", "--calibrate", "20")) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "ranges.csv: --calibrate" in err
    assert "9 of 9 steps have a fix (needs 20)" in err and "10: 9, 11: 9" in err and "each link needs 20" in err
    assert not out.exists()


def test_eval_refuses_framing_faster_than_the_links_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges, truth = write_ranges(tmp_path, 60.0, 4.0, round_robin=True)  # each link at 0.5 Hz
    assert main(_argv(ranges, truth, tmp_path / "o", "--rate", "4", "--sync")) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "ranges.csv: --rate" in err
    assert "framing at 4 Hz: only 0% of the frames hold the 3 readings a fix needs" in err
    assert "10: 0.50" in err and "17: 0.50" in err and "frame at 1.3 Hz or slower" in err
    # Framed at 0.5 Hz every frame holds all eight links: it runs.
    assert main(_argv(ranges, truth, tmp_path / "ok", "--rate", "0.5", "--sync")) == 0


def test_eval_records_what_it_calibrated(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ranges, truth = write_ranges(tmp_path, 40.0, 10.0, round_robin=False)
    out = tmp_path / "o"
    assert main(_argv(ranges, truth, out, "--rate", "10", "--calibrate", "10")) == 0
    text = capsys.readouterr().out
    assert "Calibration (" in text and "10: 101 x" in text
    res = json.loads((out / "results.json").read_text())
    for name in ("ekf", "secekf"):
        (rep,) = res["estimators"][name]["calibration"]
        assert rep["status"] == "calibrated" and rep["window_s"] == 10.0
        assert rep["links"]["17"]["readings"] == 101 and {"offset_m", "sigma_m"} <= set(rep["links"]["17"])


def test_a_flight_too_short_for_its_window_is_refused_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Flown trials (here two, in worker processes) count the window the same way: 1 s at 10 Hz is 11 steps."""
    argv = ["--scenario", "anchors8", "--attack", "none", "--estimators", "ekf", "--trials", "2", "--jobs", "2",
            "--duration", "3", "--calibrate", "1", "--out", str(tmp_path / "o")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("secuav-eval: --calibrate: calibration window 1 s holds too few readings")
    assert "11 of 11 steps have a fix (needs 20)" in err and not (tmp_path / "o").exists()

"""A study cell on recorded ranges (``recording:``): real ``secuav-study`` on a LocalCluster, attacks injected
by the engine on the recording, the calibration option passed as an estimator parameter."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario
from study.spec import expand, parse_study

STUDY = Path(sys.executable).parent / "secuav-study"
RATE_HZ, SECONDS = 10.0, 40.0


def _recording(folder: Path) -> None:
    """anchors8's vehicle circling its centre; ranges with per-link offsets, as a real UWB set reads."""
    anchors = load_scenario("anchors8").anchor_positions()
    rng = np.random.default_rng(5)
    bias = rng.normal(0.17, 0.06, len(anchors))
    t = np.arange(0.0, SECONDS, 1.0 / RATE_HZ)
    pos = np.column_stack([2.5 + np.cos(0.2 * t), 2.5 + np.sin(0.2 * t), np.full(t.shape, -2.5)])
    with (folder / "ranges.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sensor_id", "range_m"])
        for tk, p in zip(t, pos, strict=True):
            for a in sorted(anchors):
                d = float(np.linalg.norm(p - np.array(anchors[a]))) + bias[a] + rng.normal(0.0, 0.07)
                w.writerow([f"{tk:.2f}", 10 + a, f"{d:.3f}"])
    with (folder / "truth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, p in zip(t, pos, strict=True):
            w.writerow([f"{tk:.2f}", 1, *(f"{v:.4f}" for v in p)])


STUDY_TEXT = """
name: recorded
scenario: anchors8
dims: 2
recording: {ranges: ranges.csv, truth: truth.csv}
estimators: [ekf, secekf]
estimator_params: {calibration_s: [null, 15.0]}
seeds: 1
attacks:
  - none
  - profile: anchors-constant
    params: {offset_m: 1.5, start_s: 25.0}
"""


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_study_on_recorded_ranges(tmp_path: Path) -> None:
    _recording(tmp_path)
    study = tmp_path / "study.yaml"
    study.write_text(STUDY_TEXT.replace("{calibration_s: [null, 15.0]}", "{calibration_s: [15.0]}"))
    out = tmp_path / "out"
    done = subprocess.run(
        [str(STUDY), "run", str(study), "--out", str(out), "--workers", "1", "--no-progress"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1])["ran"] == 2
    rows = pd.read_parquet(out / "results.parquet")
    # ls: the undefended least-squares baseline, run in every offline study though not listed.
    assert (rows["status"] == "ok").all() and len(rows) == 8
    assert set(rows["estimator"]) == {"ls", "ekf", "secekf", "secekf+attribution"}
    attacked = rows[rows["attack"] != "none"].set_index("estimator")
    assert attacked.loc["secekf", "rmse_m"] < attacked.loc["ekf", "rmse_m"]
    assert rows.loc[rows["attack"] == "none", "estimator_params"].notna().all()  # calibration_s went along
    assert set(rows["recording"]) == {"ranges.csv"}  # an unnamed single recording: its ranges file as written
    report = (out / "report.md").read_text()
    assert "| RMSE / LS |" in report and "| none | ls calibration_s=15.0 | " in report  # clean table, Table 5.1
    # own_false_naming, attribution_false_naming (ls claims nothing; secekf's own output has no attribution)
    assert re.search(r"\| ls calibration_s=15.0 \| leg hover \| 1 \| n/a \| n/a \| [0-9.]+ \| 1\.00 \|", report)
    assert re.search(r"\| secekf calibration_s=15.0 \| leg hover \| 1 \| [0-9.]+ \| n/a \| [0-9.]+ \| [0-9]\.[0-9]{2}",
                     report)  # fmt: skip
    assert re.search(r"\| secekf\+attribution calibration_s=15.0 \| leg hover \| 1 \| [0-9.]+ \| [0-9.]+ \| [0-9.]+",
                     report)  # fmt: skip
    # What the window did, per row: every link's readings used, offset and scale.
    for text in rows["calibration"]:
        rep = json.loads(text)
        assert rep["status"] == "calibrated" and rep["window_s"] == 15.0 and len(rep["links"]) == 8
        assert all(v["readings"] == 151 and abs(v["offset_m"]) < 0.5 for v in rep["links"].values())


def test_recording_cells_are_keyed_by_content_and_refused_where_they_make_no_sense(tmp_path: Path) -> None:
    _recording(tmp_path)
    source = str(tmp_path / "study.yaml")
    cells = expand(parse_study(STUDY_TEXT, source), source)
    assert len(cells) == 4 and all(c.recording is not None for c in cells)
    assert cells[0].recording.streams[1].readings[10].shape == (SECONDS * RATE_HZ,)
    keys = {c.key for c in cells}
    (tmp_path / "ranges.csv").write_text((tmp_path / "ranges.csv").read_text().replace("3.", "4.", 1))
    assert not keys & {c.key for c in expand(parse_study(STUDY_TEXT, source), source)}  # new content, new cells
    with pytest.raises(InputError, match="recording"):
        parse_study(STUDY_TEXT + "legs: [moving]\n", source)
    with pytest.raises(InputError, match=r"recording.*no such file"):
        expand(parse_study(STUDY_TEXT.replace("ranges.csv", "gone.csv"), source), source)


def test_a_window_too_sparse_to_calibrate_fails_the_study_file(tmp_path: Path) -> None:
    """A study's calibration window that holds too few readings is refused at validation, with one line naming
    each link's count and what it needs, instead of running uncalibrated while the rows say calibration_s."""
    _recording(tmp_path)
    source = str(tmp_path / "study.yaml")
    text = STUDY_TEXT.replace("{calibration_s: [null, 15.0]}", "{calibration_s: [null, 1.0]}")
    with pytest.raises(InputError) as err:
        expand(parse_study(text, source), source)
    line = str(err.value)
    assert "\n" not in line and "estimator_params.calibration_s" in line
    assert "11 of 11 steps have a fix (needs 20)" in line and "10: 11, 11: 11" in line and "each link needs 20" in line
    # Outputs too fast for the links: asynchronously the window is named (the default window covers the links'
    # reading interval, so a window of one period is given); framed: the rate.
    fast = STUDY_TEXT.replace("truth: truth.csv}", "truth: truth.csv, rate_hz: 100}")
    assert expand(parse_study(fast, source), source)  # the default window holds every link at 100 Hz
    short = STUDY_TEXT.replace("truth: truth.csv}", "truth: truth.csv, rate_hz: 100, window_s: 0.01}")
    with pytest.raises(InputError, match=r"recording.window_s: asynchronous window 0.01 s at 100 Hz: 8 link"):
        expand(parse_study(short, source), source)
    framed = STUDY_TEXT.replace("truth: truth.csv}", "truth: truth.csv, rate_hz: 100, sync: true}")
    with pytest.raises(InputError, match=r"recording.rate_hz: framing at 100 Hz: only 10% of the frames"):
        expand(parse_study(framed, source), source)

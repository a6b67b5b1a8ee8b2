"""A study cell on recorded ranges (``recording:``): real ``secuav-study`` on a LocalCluster, attacks injected
by the engine on the recording, the calibration option passed as an estimator parameter."""

from __future__ import annotations

import csv
import json
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
    assert (rows["status"] == "ok").all() and len(rows) == 4
    attacked = rows[rows["attack"] != "none"].set_index("estimator")
    assert attacked.loc["secekf", "rmse_m"] < attacked.loc["ekf", "rmse_m"]
    assert rows.loc[rows["attack"] == "none", "estimator_params"].notna().all()  # calibration_s went along


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

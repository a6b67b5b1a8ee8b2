"""One study over several recordings (``recordings:``): the real Hanyang LOS and NLOS excerpts (tests/data/hanyang_uwb),
converted by the dataset's own script, each with its own scenario, run end to end by ``secuav-study`` on a
LocalCluster; rows carry a ``recording`` column, the report has each recording's tables and one across them."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from secuav_common.loading import InputError
from study.spec import expand, parse_study
from tests.support.hanyang import TWO_RECORDINGS, convert

ROOT = Path(__file__).resolve().parents[2]
STUDY = Path(sys.executable).parent / "secuav-study"
STUDY_TEXT = "\nname: two-recordings" + TWO_RECORDINGS


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The two excerpts in the recorded-ranges format, as a user would make them (docs/datasets.md)."""
    return convert(tmp_path_factory.mktemp("hanyang"))


def _expand(folder: Path, text: str = STUDY_TEXT) -> list:
    source = str(folder / "study.yaml")
    return expand(parse_study(text, source), source)


def test_each_recording_has_its_cells_scenario_and_name(converted: Path) -> None:
    cells = _expand(converted)
    assert len(cells) == 4 and [c.recording_name for c in cells] == ["hy-los-4"] * 2 + ["hy-nlos-3"] * 2
    los, nlos = cells[0], cells[2]
    # Their own anchor layouts: the NLOS run's scenario is its own file, not the study's.
    assert los.scenario.anchor_positions() != nlos.scenario.anchor_positions()
    assert los.recording.streams is not nlos.recording.streams and len({c.key for c in cells}) == 4
    # A name is part of the key (renaming makes new rows); the content is too.
    renamed = {c.key for c in _expand(converted, STUDY_TEXT.replace("hy-los-4", "los"))}
    assert renamed & {c.key for c in cells} == {c.key for c in cells[2:]}


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t + "recording: {ranges: LOS/ranges.csv}\n", r"recording, recordings: give one .* not both"),
        (lambda t: t.replace("name: hy-nlos-3, ", ""), r"recordings\[1\]\.name: each recording needs a name"),
        (lambda t: t.replace("hy-nlos-3", "hy-los-4"), r"recordings: a name is given twice"),
        (lambda t: t.replace("dims: 2", "dims: 2\nlegs: [moving]"), r"recordings: the recording fixes the path"),
    ],
)
def test_a_bad_recordings_list_is_refused_with_its_field(converted: Path, edit, message: str) -> None:
    with pytest.raises(InputError, match=message):
        _expand(converted, edit(STUDY_TEXT))


def test_a_missing_or_sparse_recording_is_named_with_its_file_and_numbers(converted: Path) -> None:
    with pytest.raises(InputError) as err:
        _expand(converted, STUDY_TEXT.replace("NLOS/ranges.csv", "NLOS/gone.csv"))
    line = str(err.value)
    assert "\n" not in line and "recordings[1] (hy-nlos-3)" in line and "gone.csv" in line and "no such file" in line
    # Outputs too fast for one recording's links: that recording, its window (asynchronous; the default window
    # covers the links' 0.1 s reading interval, so one is given) or, framed, its rate, and the numbers.
    fast = STUDY_TEXT.replace("truth: NLOS/truth.csv, rate_hz: 10", "truth: NLOS/truth.csv, rate_hz: 200")
    _expand(converted, fast)  # the default window, 0.1 s, holds every link at 200 Hz
    with pytest.raises(InputError) as err:
        _expand(converted, fast.replace("rate_hz: 200", "rate_hz: 200, window_s: 0.005"))
    line = str(err.value)
    assert "\n" not in line and "recordings[1] (hy-nlos-3).window_s" in line and "window 0.005 s at 200 Hz" in line
    assert "(file NLOS/ranges.csv)" in line
    with pytest.raises(InputError) as err:
        _expand(converted, fast.replace("rate_hz: 200", "rate_hz: 200, sync: true"))
    line = str(err.value)
    assert "\n" not in line and "recordings[1] (hy-nlos-3).rate_hz" in line and "framing at 200 Hz" in line
    # A study-wide calibration window too short: the first recording that cannot fill it, its file and counts.
    short = STUDY_TEXT.replace("seeds: 1", "seeds: 1\nestimator_params: {calibration_s: 1.0}")
    with pytest.raises(InputError) as err:
        _expand(converted, short)
    line = str(err.value)
    assert "\n" not in line and "recordings[0] (hy-los-4), estimator_params.calibration_s" in line
    assert "(needs 20)" in line and "(file LOS/ranges.csv)" in line


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_study_over_two_real_recordings(converted: Path, tmp_path: Path) -> None:
    study = converted / "study.yaml"
    study.write_text(STUDY_TEXT)
    out = tmp_path / "out"
    done = subprocess.run(
        [str(STUDY), "run", str(study), "--out", str(out), "--workers", "1", "--no-progress"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1])["ran"] == 4
    rows = pd.read_parquet(out / "results.parquet")
    assert (rows["status"] == "ok").all() and len(rows) == 16  # secekf twice: its own output and attributed
    both = ["ekf", "ekf", "ls", "ls", "secekf", "secekf", "secekf+attribution", "secekf+attribution"]
    assert rows.groupby("recording")["estimator"].apply(sorted).to_dict() == {"hy-los-4": both, "hy-nlos-3": both}
    report = (out / "report.md").read_text()
    # Each recording's own tables ...
    for name in ("hy-los-4", "hy-nlos-3"):
        clean = rows[(rows["recording"] == name) & (rows["attack"] == "none")].set_index("estimator")
        ratio = clean.loc["secekf", "rmse_m"] / clean.loc["ls", "rmse_m"]
        line = next(x for x in report.splitlines() if x.startswith(f"| secekf | recording {name} | 1 |"))
        assert f"| {clean.loc['secekf', 'rmse_m']:.3f} | {ratio:.2f}" in line, line
        assert f"recording {name}:" in report  # the attack section's block
    # ... and across them, each recording weighted the same.
    assert "## Across 2 recordings: hy-los-4, hy-nlos-3" in report  # the study file's order
    assert report.index("recording hy-los-4:") < report.index("recording hy-nlos-3:")
    attacked = rows[rows["attack"] == "anchors-constant"].pivot(index="recording", columns="estimator", values="rmse_m")
    ratios = attacked["secekf"] / attacked["ls"]
    line = next(x for x in report.splitlines() if x.startswith("| anchors-constant |") and "| secekf | 2/2 |" in x)
    assert f"| {attacked['secekf'].mean():.3f} |" in line
    assert f"| {ratios.mean():.2f} ({ratios.min():.2f}-{ratios.max():.2f}) |" in line
    worst = rows.loc[(rows["attack"] == "anchors-constant") & (rows["estimator"] == "secekf"), "max_error_m"].max()
    assert re.search(rf"\| {worst:.3f} \|", line)
    alarms = rows[(rows["attack"] == "anchors-constant") & (rows["estimator"] == "secekf")]["own_alarm_fraction"].mean()
    assert line.endswith(f"| {alarms:.3f} |")

"""``secuav-study export`` of a study on recordings: the bundle carries the recordings' files and their own
scenarios, so ``secuav-study run BUNDLE/study.yaml`` computes the same rows with the originals gone. On the real
Hanyang LOS and NLOS excerpts (tests/data/hanyang_uwb), converted by the dataset's own script."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from secuav_common.loading import InputError
from study.bundle import export, save_inputs
from study.spec import load_study
from study.store import load
from tests.support.hanyang import TWO_RECORDINGS, convert

STUDY = Path(sys.executable).parent / "secuav-study"
STUDY_TEXT = "name: exported-recordings\n" + TWO_RECORDINGS


def _run(study: Path, out: Path, cwd: Path) -> None:
    argv = [str(STUDY), "run", str(study), "--out", str(out), "--workers", "1", "--no-progress"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=cwd, check=False)
    assert done.returncode == 0, done.stderr


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_bundle_of_a_recordings_study_reproduces_its_rows_without_the_originals(tmp_path: Path) -> None:
    author = convert(tmp_path / "author")
    (author / "study.yaml").write_text(STUDY_TEXT)
    out, bundle = tmp_path / "out", tmp_path / "bundle"
    _run(author / "study.yaml", out, cwd=author)
    export(out, bundle)
    for name in ("LOS/ranges.csv", "LOS/truth.csv", "NLOS/ranges.csv", "NLOS/truth.csv"):
        assert (bundle / name).read_bytes() == (author / name).read_bytes()
    shipped = yaml.safe_load((bundle / "study.yaml").read_text())
    assert shipped["recordings"][1]["scenario"] == "recordings/hy-nlos-3/scenario.yaml"
    assert (bundle / "recordings" / "hy-nlos-3" / "scenario.yaml").is_file()

    shutil.rmtree(author)  # another machine: only the bundle
    again = tmp_path / "again"
    _run(bundle / "study.yaml", again, cwd=tmp_path)
    then, now = load(out).set_index(["cell", "estimator"]), load(again).set_index(["cell", "estimator"])
    assert len(now) == len(then) == 16 and (now["status"] == "ok").all()  # the same cells (keys), every one
    same = ["recording", "attack", "rmse_m", "mean_error_m", "max_error_m", "valid_fraction", "own_recall"]
    pd.testing.assert_frame_equal(now.sort_index()[same], then.sort_index()[same])


def test_an_unnamed_recording_keeps_its_path_when_it_can(tmp_path: Path) -> None:
    """Its rows' recording column is the ranges path as written: kept inside the study's folder; a file from
    elsewhere goes to recordings/recording/ (the study's own bundle names are never overwritten)."""
    data = convert(tmp_path / "data")
    study_dir = tmp_path / "study"
    study_dir.mkdir()
    shutil.copytree(data / "LOS", study_dir / "LOS")
    study_file = study_dir / "study.yaml"
    text = STUDY_TEXT.split("recordings:")[0] + "recording: {ranges: LOS/ranges.csv, truth: ../data/LOS/truth.csv}\n"
    study_file.write_text(text + "estimators: [secekf]\nseeds: 1\nattacks: [none]\n")
    out = tmp_path / "out"
    save_inputs(out, load_study(study_file), study_file)
    saved = yaml.safe_load((out / "inputs" / "study.yaml").read_text())["recording"]
    assert saved == {"ranges": "LOS/ranges.csv", "truth": "recordings/recording/truth.csv"}
    assert (out / "inputs" / "LOS" / "ranges.csv").read_bytes() == (data / "LOS" / "ranges.csv").read_bytes()
    assert (out / "inputs" / saved["truth"]).read_bytes() == (data / "LOS" / "truth.csv").read_bytes()


def test_inputs_without_the_recording_files_are_refused_in_one_line(tmp_path: Path) -> None:
    """A directory run before recordings were copied: one line naming the field, not a bundle that cannot run."""
    inputs = tmp_path / "out" / "inputs"
    inputs.mkdir(parents=True)
    (inputs / "study.yaml").write_text(STUDY_TEXT.replace("scenario: LOS/scenario.yaml", "scenario: scenario.yaml"))
    refused = r"recordings\[0\]\.ranges: not among the run.s inputs: run the study again .*LOS/ranges.csv"
    with pytest.raises(InputError, match=refused):
        export(tmp_path / "out", tmp_path / "bundle")

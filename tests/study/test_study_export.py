"""``secuav-study export``: a bundle that ``secuav-study run`` elsewhere turns into the same rows."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

STUDY = Path(sys.executable).parent / "secuav-study"

TEXT = """
name: bundle-me
scenario: anchors8
duration_s: 4
estimators: [ekf, {name: secekf, params: {window: [5, 10]}}]
seeds: 1
attacks:
  - none
  - profile: my-attack.yaml
    params: {offset_m: 1.0}
"""

PROFILE = """
name: my-attack
parameters: {offset_m: {default: 0.5}}
rules:
  - kind: bias
    target: {message: DISTANCE_SENSOR, sensor_id: [11, 14]}
    offset: $offset_m
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(STUDY), *args], capture_output=True, text=True, timeout=300, check=False)


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_an_exported_bundle_reproduces_the_rows_row_for_row(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    (src / "study.yaml").write_text(TEXT)
    (src / "my-attack.yaml").write_text(PROFILE)
    out = tmp_path / "out"
    assert _run("run", str(src / "study.yaml"), "--out", str(out), "--workers", "1", "--no-progress").returncode == 0
    bundle = tmp_path / "bundle"
    done = _run("export", str(out), str(bundle))
    assert done.returncode == 0, done.stderr
    assert {p.name for p in bundle.iterdir()} >= {"study.yaml", "scenario.yaml", "profiles", "environment.json",
                                                  "results.csv", "results.parquet", "report.md"}  # fmt: skip
    env = json.loads((bundle / "environment.json").read_text())
    assert env["exported_by"]["numpy_version"] and "secuav" in env["installed"]
    # elsewhere: only the bundle (the original inputs are gone)
    for path in src.iterdir():
        path.unlink()
    again = tmp_path / "again"
    done = _run("run", str(bundle / "study.yaml"), "--out", str(again), "--workers", "1", "--no-progress")
    assert done.returncode == 0, done.stderr
    before = pd.read_csv(bundle / "results.csv")
    after = pd.read_parquet(again / "results.parquet")
    # ekf, secekf at two windows (each its own output and with the attribution), and the ls baseline
    assert len(before) == len(after) == 2 * 6
    both = before.merge(after, on=["cell", "estimator"], suffixes=("_then", "_now"))
    assert len(both) == len(before)
    for col in ("rmse_m", "max_error_m", "own_alarm_fraction", "attribution_recall", "attribution_false_naming",
                "output", "code_key", "attack_hash"):  # fmt: skip
        assert both[f"{col}_then"].equals(both[f"{col}_now"].rename(f"{col}_then")), col  # NaN = NaN here


def test_export_needs_a_run_and_an_empty_target(tmp_path: Path) -> None:
    done = _run("export", str(tmp_path / "nothing"), str(tmp_path / "b"))
    assert done.returncode == 2 and "inputs/study.yaml" in done.stderr

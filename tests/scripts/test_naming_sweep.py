"""scripts/naming_sweep.py (the sweep that chose the naming band of estimators/offsets.py) run for real through its
``main`` on the bundled LIAS excerpt (tests/data/lias_planar, 20 s of the mid run): it rests on
scripts/recorded_alarms.py's cells and figures, so a change there that breaks it fails here, not silently."""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import pytest

from estimators import noise, offsets
from tests.support.markdown import tables

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "naming_sweep.py"
CONVERT = ROOT / "scripts" / "datasets" / "lias_planar_uwb.py"
EXCERPT = ROOT / "tests" / "data" / "lias_planar"
# the excerpt is 20 s long: the documented protocol (20 / 21 / 30 s) shortened, as in test_recorded_report.py
SHORT = ["--calibrate", "8", "--score-from", "9", "--onset", "12", "--estimators", "secekf"]


def _sweep():
    spec = importlib.util.spec_from_file_location("naming_sweep", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module



def _numbers(cell: str) -> list[float]:
    """The figures in a cell such as ``0.209 / 0.30`` or ``0.791, 4, 1309/h``."""
    parts = cell.replace("/h", "").replace(" / ", ",").replace("(max", ",").replace(")", "").replace(" ", ",")
    return [float(p) for p in parts.split(",") if p]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "lias-mid-0"
    cmd = [sys.executable, str(CONVERT), "convert", "--source", str(EXCERPT), "--run", "mid", "--tag", "0",
           "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    return out


def test_sweep_prints_excursions_and_a_row_per_band_and_estimator(
    recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    band, tracker = offsets.BAND_M, noise.OffsetTracker
    assert _sweep().main([str(recording), "--bands", "off,0.25", *SHORT]) == 0
    assert (offsets.BAND_M, noise.OffsetTracker) == (band, tracker)  # the band is put back
    excursions, sweep = tables(capsys.readouterr().out)
    assert [r[0] for r in excursions[1:]] == ["lias-mid-0"]
    largest, p99 = (_numbers(c) for c in excursions[1][1:])
    assert len(largest) == 8 + 1 and len(p99) == 8  # eight links (and the largest of them)
    assert all(math.isfinite(v) and v >= 0 for v in largest + p99)
    header, rows = sweep[0], sweep[1:]
    assert len(header) == 8 and header[:3] == ["band [m]", "recording", "estimator"]
    assert [r[:3] for r in rows] == [["off", "lias-mid-0", "secekf"], ["0.25", "lias-mid-0", "secekf"]]
    figures = {r[0]: [_numbers(c) for c in r[3:]] for r in rows}
    for values in figures.values():
        assert [len(v) for v in values] == [2, 3, 3, 2, 1]
        assert all(math.isfinite(v) for cell in values for v in cell)  # the ramp named at a finite size too
        (_, _), (named, _, _), (alarms, _, _), (recall, _), _ = values
        assert 0 <= named <= 1 and 0 <= alarms <= 1 and 0 <= recall <= 1
    # the band reaches the estimators run by recorded_alarms: without it honest links are named on this excerpt
    assert figures["off"][1][0] > figures["0.25"][1][0]


def test_floor_prints_each_bias_and_sign(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = [str(recording), "--bands", "0.25", "--links", "1", "--no-excursions", "--floor", "0.5", *SHORT]
    assert _sweep().main(argv) == 0
    (table,) = tables(capsys.readouterr().out)
    assert table[0] == ["band [m]", "recording", "estimator", "+0.5 m", "-0.5 m"]
    assert [r[:3] for r in table[1:]] == [["0.25", "lias-mid-0", "secekf"]]
    assert all(0.0 <= float(c) <= 1.0 for c in table[1][3:])

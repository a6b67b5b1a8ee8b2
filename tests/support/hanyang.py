"""The Hanyang LOS and NLOS excerpts (tests/data/hanyang_uwb) converted by the dataset's own script, as a user
would (docs/datasets.md), and a study over both, each recording with its own scenario, for the study tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONVERT = ROOT / "scripts" / "datasets" / "hanyang_outdoor_uwb.py"
EXCERPT = ROOT / "tests" / "data" / "hanyang_uwb"

TWO_RECORDINGS = """
scenario: LOS/scenario.yaml
dims: 2
recordings:
  - {name: hy-los-4, ranges: LOS/ranges.csv, truth: LOS/truth.csv, rate_hz: 10}
  - {name: hy-nlos-3, ranges: NLOS/ranges.csv, truth: NLOS/truth.csv, rate_hz: 10, scenario: NLOS/scenario.yaml}
estimators: [secekf]
seeds: 1
attacks:
  - none
  - profile: anchors-constant
    params: {offset_m: 1.5, start_s: 15.0, links: [11, 13]}
"""  # a study file without its name: "name: ..." first


def convert(folder: Path) -> Path:
    """LOS case 4 into ``folder/LOS`` and NLOS case 3 into ``folder/NLOS``: ranges.csv, truth.csv, scenario.yaml."""
    for env, case in (("LOS", 4), ("NLOS", 3)):
        argv = [sys.executable, str(CONVERT), "convert", "--source", str(EXCERPT), "--env", env, "--case", str(case),
                "--out", str(folder / env)]  # fmt: skip
        subprocess.run(argv, check=True, capture_output=True, timeout=120)
    return folder

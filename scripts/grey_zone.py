#!/usr/bin/env python
"""Why the secure estimators can be worse than the plain EKF on some valid steps in the grey zone.

The grey zone: more links attacked than test case 1 tolerates (s = 2), by so
little that one step's readings do not prove it. There, some valid steps of every
secure estimator are further from the truth than the EKF ever is in the same run.
This script finds those steps and asks of each one what the readings of that step
alone allow: it runs the exact fewest-liars decoder on them (every subset that
leaves out s readings, fitted by Gauss-Newton started AT THE TRUTH, kept when its
chi-square statistic passes at the estimators' alpha) and reports

- ``l0 worse``: the share of those steps where the decoder's answer (the passing
  subset with the smallest statistic) is itself further from the truth than the
  EKF's worst step: the exact reference the estimators are checked against
  makes the same mistake from the same readings;
- ``all worse``: the share where EVERY passing explanation is: whichever
  (p - s)-subset a decoder trusted, it could not have matched the EKF. The
  readings then fit a false position with at most s liars as well as clean
  readings fit the truth, and nothing in that step tells the attack from a
  within-tolerance one on honest links.

The clean runs come first, as the baseline: an estimator that leaves readings
out is noisier than an EKF that smooths all of them, so some clean valid steps
are further off than the EKF's worst too (the price of resilience).

Usage (the cells are test-case-1's own, from studies/test-case-1.yaml):
    .venv/bin/python scripts/grey_zone.py --seeds 5
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimators.attribution import agreeing  # noqa: E402
from estimators.bank import Chi2Table  # noqa: E402
from estimators.models import MeasurementModel  # noqa: E402
from estimators.scenario_models import anchor_model  # noqa: E402
from evaluation.trial import run_trial  # noqa: E402
from study.spec import Cell, expand, load_study  # noqa: E402

GREY = (
    ("none", {}),
    ("anchors-relay", {"excess_m": 0.3}),
    ("anchors-relay", {"excess_m": 0.5}),
    ("anchors-overwhelm", {"offset_m": 0.3}),
)
SECURE = ("secekf", "secopt", "recap", "rarse", "l0")


@dataclass
class Tally:
    steps: int = 0  # valid steps scored
    worse: int = 0  # of them, further from the truth than the EKF's worst step of the run
    l0_worse: int = 0  # of those, where the step's fewest-liars answer is too
    all_worse: int = 0  # of those, where every passing explanation is too
    excess_m: float = 0.0  # the largest amount by which a valid step exceeded the EKF's worst


def _decode(model: MeasurementModel, chi: Chi2Table, z: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Horizontal errors of the passing (p - s)-subset fits of one step's readings, best statistic first."""
    level = agreeing(model, z, model.max_correctable, chi, truth, None)
    idx = np.flatnonzero(level.passing)
    idx = idx[np.argsort(level.stat[idx])]
    return np.linalg.norm(level.pos[idx, :2] - truth[:2], axis=1)


def tally_cell(cell: Cell, tallies: dict[str, Tally], alpha: float) -> None:
    trial = run_trial(
        cell.scenario,
        cell.profile,
        ["ekf", *SECURE],
        cell.seed,
        cell.duration_s,
        cell.leg,
        cell.estimator_params,
        cell.dims,
    )
    ekf_worst = float(np.nanmax(trial.traces["ekf"].err_m))
    if trial.readings_m is None or trial.truth_down_m is None:
        raise ValueError(f"{cell.key}: the trial kept no readings to decode")
    model = anchor_model(cell.scenario, cell.scenario.vehicles[0].sysid, cell.dims)
    chi = Chi2Table(alpha, 4 * model.p)
    # The truth in the model's state: north, east and, with the laser as a reading, down.
    stream_truth = trial.truth_xy_m
    for name in SECURE:
        tr, t = trial.traces[name], tallies[name]
        valid = ~tr.degraded & np.isfinite(tr.err_m)
        t.steps += int(valid.sum())
        for k in np.flatnonzero(valid & (tr.err_m > ekf_worst)):
            t.worse += 1
            t.excess_m = max(t.excess_m, float(tr.err_m[k] - ekf_worst))
            truth = np.append(stream_truth[k], trial.truth_down_m[k]) if cell.dims == 3 else stream_truth[k]
            errs = _decode(model, chi, trial.readings_m[k], truth)
            t.l0_worse += bool(errs.size and errs[0] > ekf_worst)
            t.all_worse += bool(errs.size and np.all(errs > ekf_worst))


def _share(part: int, whole: int) -> str:
    return f"{part / whole:.0%}" if whole else "-"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5, help="the first N seeds of each cell (default 5)")
    ap.add_argument("--alpha", type=float, default=0.01, help="the estimators' false-alarm level")
    args = ap.parse_args(argv)
    path = ROOT / "studies" / "test-case-1.yaml"
    cells = [c for c in expand(load_study(path), str(path)) if (c.attack, c.params) in GREY and c.seed < args.seeds]
    print(f"{len(cells)} cells", file=sys.stderr)
    for attack, params in GREY:
        tallies = {name: Tally() for name in SECURE}
        mine = [c for c in cells if c.attack == attack and c.params == params]
        for i, cell in enumerate(mine, 1):
            tally_cell(cell, tallies, args.alpha)
            print(f"  {attack} {json.dumps(params)}: {i}/{len(mine)}", file=sys.stderr, end="\r")
        print(f"\n{attack} {json.dumps(params)} ({len(mine)} runs)")
        print("| estimator | valid steps | worse than the EKF's worst | l0 worse | all worse | largest excess (m) |")
        print("|---|---|---|---|---|---|")
        for name, t in tallies.items():
            l0, every = _share(t.l0_worse, t.worse), _share(t.all_worse, t.worse)
            print(f"| {name} | {t.steps} | {t.worse} | {l0} | {every} | {t.excess_m:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

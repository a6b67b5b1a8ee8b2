"""What the held-out layouts' geometry allows a secure estimator, before any estimator runs.

    .venv/bin/python scripts/heldout_geometry.py --sigma 0.3     # studies/scenarios/heldout{1,2,3}.yaml

Per layout, at its hover point, with every UWB link's noise std set to ``--sigma`` (the laser keeps its own):

- ``s``: the most attacked readings the layout can correct over its flight region (observability.py);
- ``crb``: the Cramer-Rao bound on the horizontal RMSE with every reading, sqrt(trace of the horizontal block of
  (H^T R^-1 H)^-1), H the range Jacobian at the hover point;
- ``keep p - s``: over every subset of p - s readings (what a subset bank's output rests on: SecEKF, SecOPT,
  ReCaP's search, l0), the same bound over the all-readings one: its minimum, median and maximum. An unbiased
  estimator on that subset cannot do better than this ratio against one on all readings, whatever its tests;
- ``l0 bound``: the worst-case horizontal error an exact l0 decoder can be driven to by s liars with noise
  inside 3 sigma (estimators.bounds), i.e. what "robust" can promise within tolerance on this geometry;
- beyond s (the three-link relay), no estimator can tell the honest picture from the liars' in general: p - 2 * 3
  readings remain to agree on, fewer than the unknowns plus one, so nothing bounds the error.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimators.bounds import l0_error_bound
from estimators.scenario_models import anchor_model
from secuav_common.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def crb_horizontal(jac: np.ndarray, sigma: np.ndarray) -> float:
    info = (jac / sigma[:, None] ** 2).T @ jac
    return float(np.sqrt(np.trace(np.linalg.inv(info)[:2, :2])))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sigma", type=float, default=0.3, help="UWB noise std told and flown, metres")
    ap.add_argument("--layouts", nargs="*", default=["heldout1", "heldout2", "heldout3"])
    args = ap.parse_args(argv)
    print("| layout | s | CRB all readings [m] | keep p - s: CRB ratio min / median / max | l0 bound (3 sigma) [m] |")
    print("|---|---|---|---|---|")
    for name in args.layouts:
        scenario = load_scenario(ROOT / "studies" / "scenarios" / f"{name}.yaml")
        model = anchor_model(scenario)
        sigma = model.sigma_m.copy()
        sigma[: model.p - 1] = args.sigma  # the UWB links; the laser (last reading) keeps its std
        model = replace(model, sigma_m=sigma)
        hold = np.array(scenario.vehicles[0].target.pos_ned_m, dtype=float)
        pos = hold[: model.d]
        jac = np.asarray(model.jac(pos, model.default_known), dtype=float)
        s = model.max_correctable
        full = crb_horizontal(jac, sigma)
        ratios = [
            crb_horizontal(jac[list(keep)], sigma[list(keep)]) / full
            for keep in itertools.combinations(range(model.p), model.p - s)
        ]
        bound = l0_error_bound(model, pos, s, 3.0 * sigma, model.default_known, slice(0, 2))
        lo, med, hi = np.min(ratios), np.median(ratios), np.max(ratios)
        print(f"| {name} | {s} | {full:.3f} | {lo:.2f} / {med:.2f} / {hi:.2f} | {bound:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

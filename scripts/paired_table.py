"""Paired per-seed comparisons with the plain EKF from a study's rows.

    .venv/bin/python scripts/paired_table.py out/motion-input [--metric rmse_m valid_max_error_m]

For every cell group (attack, its parameters, leg, position, noise scale) and every estimator variant (the estimator
and its non-null estimator_params), each seed's figure minus the plain EKF's (defaults) on the same
seed: the mean difference with a 95 % bootstrap interval, and on how many seeds the variant was worse.
Metrics: ``rmse_m`` (every step), ``valid_max_error_m`` (the worst step claimed valid; the EKF claims
every step), ``max_error_m``. Also the variant's own mean and the claimed-valid share. No netting of
the clean price: the clean cells are rows like any other.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from study.store import load


def _variant(row: pd.Series) -> str:
    params = json.loads(row["estimator_params"]) if isinstance(row["estimator_params"], str) else {}
    set_params = {k: v for k, v in (params or {}).items() if v is not None}
    return row["estimator"] + "".join(f" {k}={v}" for k, v in sorted(set_params.items()))


def _ci(values: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    boots = rng.choice(values, size=(2000, values.size)).mean(axis=1)
    return float(np.percentile(boots, 2.5)), float(np.percentile(boots, 97.5))


def table(rows: pd.DataFrame, metrics: list[str], baseline: str = "ekf") -> list[str]:
    rng = np.random.default_rng(0)
    rows = rows[rows["status"] == "ok"].copy()
    rows["variant"] = rows.apply(_variant, axis=1)
    rows["group"] = (
        rows["attack"] + " " + rows["params"].fillna("") + " " + rows["leg"] + " " + rows["position"].fillna("")
        + rows["noise_scale"].map(lambda k: "" if k == 1.0 else f" noise x{k:g}")
    )
    heads = " | ".join(f"{m} (variant) | {m} minus {baseline} [95% CI] (worse on)" for m in metrics)
    out = [f"| cell | variant | n | {heads} | claimed valid |", "|---|---|---|" + "---|---|" * len(metrics) + "---|"]
    for group, cells in rows.groupby("group", sort=True):
        base = cells[cells["variant"] == baseline].set_index("seed")
        for variant, sub in cells.groupby("variant", sort=True):
            if variant == baseline:
                continue
            sub = sub.set_index("seed")
            seeds = sub.index.intersection(base.index)
            if seeds.empty:
                continue
            parts = []
            for m in metrics:
                own = sub.loc[seeds, m].to_numpy(float)
                ref = base.loc[seeds, "rmse_m" if m == "valid_rmse_m" else m].to_numpy(float)
                if m == "valid_max_error_m":
                    ref = base.loc[seeds, "max_error_m"].to_numpy(float)  # the EKF claims every step
                diff = own - ref
                ok = np.isfinite(diff)
                if not ok.any():
                    parts.append(f"{np.nanmean(own) if np.isfinite(own).any() else float('nan'):.3f} | n/a")
                    continue
                lo, hi = _ci(diff[ok], rng)
                parts.append(f"{np.nanmean(own):.3f} | {diff[ok].mean():+.3f} [{lo:+.3f}, {hi:+.3f}] "
                             f"({int((diff[ok] > 0).sum())}/{int(ok.sum())})")  # fmt: skip
            valid = sub.loc[seeds, "valid_fraction"].to_numpy(float)
            cols = " | ".join(parts)
            out.append(f"| {group.strip()} | {variant} | {len(seeds)} | {cols} | {np.nanmean(valid):.0%} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="a study's output directory")
    ap.add_argument("--metric", nargs="+", default=["rmse_m", "valid_max_error_m"])
    ap.add_argument("--baseline", default="ekf")
    args = ap.parse_args(argv)
    print("\n".join(table(load(args.out), args.metric, args.baseline)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

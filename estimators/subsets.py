"""Choosing among subset hypotheses "sensors outside S are attacked", shared by the secure estimators.

A subset passes when its statistic stays under the chi-square quantile of its
degrees of freedom (false-alarm level alpha). Among the passing subsets the
one using the most readings wins (fewest sensors discarded), ties broken by the
smallest statistic. If none passes, more than s sensors are attacked (or the
model is wrong): alarm, and the least-bad subset is returned for coasting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.bank import Chi2Table, GnResult, gauss_newton, inv_small, subset_masks
from estimators.models import Known, MeasurementModel


@dataclass(frozen=True, eq=False)
class Choice:
    index: int  # winning subset (row of the masks)
    passing: np.ndarray  # (J,) bool
    alarm: bool


def choose(stat: np.ndarray, dof: np.ndarray, n_used: np.ndarray, valid: np.ndarray, chi: Chi2Table) -> Choice:
    """Pick a subset from per-subset statistics (see module docstring)."""
    passing = valid & (stat <= chi(dof))
    # Windows of different lengths (a subset re-judged after a change) compare by
    # the statistic's standard score (E - dof) / sqrt(2 dof), not its raw sum.
    zscore = (stat - dof) / np.sqrt(2.0 * np.maximum(dof, 1))
    if passing.any():
        # Most readings first, then smallest score: lexicographic via a large multiplier.
        score = np.where(passing, zscore - 1e12 * n_used, np.inf)
        return Choice(int(np.argmin(score)), passing, False)
    score = np.where(valid, zscore, np.inf)
    idx = int(np.argmin(score)) if np.isfinite(score).any() else 0
    return Choice(idx, passing, True)


@dataclass(frozen=True, eq=False)
class SnapshotChoice:
    pos: np.ndarray  # (d,)
    cov: np.ndarray  # (d, d)
    use: np.ndarray  # (p,) bool: readings of the winning subset
    alarm: bool
    fits: GnResult


def secure_snapshot(
    model: MeasurementModel,
    z: np.ndarray,
    s: int,
    chi: Chi2Table,
    start: np.ndarray | None = None,
    known: Known = None,
    n_iter: int = 6,
) -> SnapshotChoice:
    """One-step l0 decoder: weighted LS on every subset of p - s sensors, pick a consistent one.

    Statistic: the subset's weighted residual sum of squares, chi-square with
    (readings used - d) dof when the subset is clean.
    """
    masks = subset_masks(model.p, model.p - s)
    fits = gauss_newton(model, z, masks, model.initial_pos() if start is None else start, known, n_iter)
    dof = fits.n_used - model.d
    choice = choose(fits.cost, dof, fits.n_used, fits.n_used >= model.min_sensors, chi)
    j = choice.index
    use = masks[j] & ~np.isnan(z)
    return SnapshotChoice(fits.pos[j], inv_small(fits.info[j : j + 1])[0], use, choice.alarm, fits)

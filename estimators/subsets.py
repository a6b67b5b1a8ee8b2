"""Choosing among subset hypotheses "sensors outside S are attacked", shared by the secure estimators.

A subset passes when its statistic stays under the chi-square quantile of its
degrees of freedom (false-alarm level alpha). Among the passing subsets the
one using the most readings wins (fewest sensors discarded), then the one with
the least accumulated :class:`Evidence` against it, then the smallest
statistic. If none passes, more than s sensors are attacked (or the model is
wrong): alarm, and the least-bad subset is returned for coasting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.bank import Chi2Table, GnResult, gauss_newton, inv_small
from estimators.models import Known, MeasurementModel


@dataclass(frozen=True, eq=False)
class Choice:
    index: int  # winning subset (row of the masks)
    passing: np.ndarray  # (J,) bool
    alarm: bool


class Evidence:
    """Evidence against each subset that builds up over time instead of being cleared.

    RECON (ours; the window tests of the bank estimators forget everything
    older than T steps, and a subset re-judged after a change starts from an
    empty window, so a subset fed by a small persistent bias keeps winning ties
    against the clean one): a one-sided CUSUM per subset of the step's
    standardised statistic ``u = (eps - dof) / sqrt(2 dof)``, which is zero-mean
    with unit variance on a clean subset:

        g <- min(limit, max(0, g + u - drift))

    A clean subset's ``g`` keeps returning to 0; a subset that contains a
    sensor biased by b sigma gains about ``b^2 / sqrt(2 dof) - drift`` per step
    for as long as the bias lasts, however small each step's share, and drains
    at ``drift`` per step once it stops. The cap keeps the ranking able to
    follow an attack that moves to other sensors: the subset that was
    attacked starts draining at once, while the newly attacked ones climb to the
    cap, so the order flips within a few steps instead of after the whole
    history has drained. Used to rank passing subsets, never to raise the alarm,
    which stays the chi-square window test at level alpha.
    """

    def __init__(self, n_subsets: int, drift: float = 0.5, limit: float = 10.0) -> None:
        self.drift = drift
        self.limit = limit
        self.g = np.zeros(n_subsets)

    def update(self, stat: np.ndarray, dof: np.ndarray) -> np.ndarray:
        """Add one step's per-subset statistic (``dof`` 0: no readings, the evidence only drains)."""
        u = np.where(dof > 0, (stat - dof) / np.sqrt(2.0 * np.maximum(dof, 1)), 0.0)
        np.clip(self.g + u - self.drift, 0.0, self.limit, out=self.g)
        return self.g


def choose(
    stat: np.ndarray,
    dof: np.ndarray,
    n_used: np.ndarray,
    valid: np.ndarray,
    chi: Chi2Table,
    evidence: np.ndarray | None = None,
) -> Choice:
    """Pick a subset from per-subset statistics (see module docstring)."""
    passing = valid & (stat <= chi(dof))
    # Windows of different lengths (a subset re-judged after a change) compare by
    # the statistic's standard score (E - dof) / sqrt(2 dof), not its raw sum.
    zscore = (stat - dof) / np.sqrt(2.0 * np.maximum(dof, 1))
    if passing.any():
        cand = np.flatnonzero(passing)
        ev = np.zeros(cand.size) if evidence is None else evidence[cand]
        # lexsort: the last key is the primary one. Most readings, least evidence, smallest score.
        order = np.lexsort((zscore[cand], ev, -n_used[cand]))
        return Choice(int(cand[order[0]]), passing, False)
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
    masks = model.honest_subsets(s)
    fits = gauss_newton(model, z, masks, model.initial_guess(z, known) if start is None else start, known, n_iter)
    dof = fits.n_used - model.d
    choice = choose(fits.cost, dof, fits.n_used, fits.n_used >= model.min_sensors, chi)
    j = choice.index
    use = masks[j] & ~np.isnan(z)
    return SnapshotChoice(fits.pos[j], inv_small(fits.info[j : j + 1])[0], use, choice.alarm, fits)

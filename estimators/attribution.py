"""Which readings a secure estimator names as attacked, at a false-alarm level a reader can check.

Every secure estimator decides two things each step: where the vehicle is
(its own algorithm) and which readings it accuses. The second is the same
question for all of them, so it is answered here, once, and a reviewer can
hold each estimator's accusations to the level ``alpha`` it was given.

Within tolerance (no alarm, or an alarm that one step's readings do not confirm)
----------------------------------------------------------------------------
A reading is named only if the estimate does not rest on it (it is outside
``Estimate.used``) and its residual against the estimate fails a test. Each
step tests p readings, so the tests are a family: every per-reading test runs at
the Sidak level ``a1 = 1 - (1 - alpha / 2)^(1 / p)``, which keeps the chance that
any honest reading is named by it at one step at ``alpha / 2``. Two tests share
the budget:
- the step's own normalised residual ``r_i^2 / (sigma_i^2 + H_i P H_i^T) >
  chi2.ppf(1 - a1, 1)`` (a jump);
- the window test: the mean residual m of the last T steps against its
  variance, ``m^2 > chi2.ppf(1 - a1, 1) (sigma_i^2 / n + H_i P H_i^T)`` (a bias
  of a few sigma that hides inside any single step's gate but not inside the
  window's mean; see :class:`Namer` for the variance).
On clean data a step therefore names an honest reading with probability at most
about alpha, whatever p is. (Before this the per-reading gate was
``chi2.ppf(1 - alpha, 1)`` for each of the p readings: eight readings at
alpha = 0.01 named an honest one on 7-9 % of clean steps.)

Beyond tolerance (the alarm is confirmed: no ``p - s`` readings agree)
-------------------------------------------------------------------
Where the vehicle can be is the :class:`Trail`: a constant-velocity filter on
the last valid position (corrected by each explanation below while degraded)
that allows a hard manoeuvre. Its prediction is the prior of every test here:
a subset agrees when its fit passes ``chi2.ppf(1 - level, readings - d + d)``
with the prior's term added (:func:`agreeing`). An alarm, or an estimate that
leaves the trail (beyond tolerance an estimator's own tests can accept a
coincidental consistent subset far off), is confirmed when no ``p - s``
readings agree at ``alpha / 10``. Then the estimator cannot correct, but it can
still say whom it suspects, and the suspicion should be right. :func:`explain`
is the l0 decoder with a growing budget of liars: for k = s + 1, s + 2, ... it
fits every subset that leaves out k readings (``model.honest_subsets(k)``) and
keeps those that agree at ``alpha``. At the smallest k where
some pass, the readings named are those *every* passing subset leaves out: the
sensors all explanations with the fewest liars agree are lying. Several
explanations that disagree (a colluding attacker who built a second consistent
picture) name only what they share, possibly nothing, and give no position;
a single explanation (or several on one position) also gives its fit, which the
caller outputs *marked degraded* (``Estimate.valid`` False), never as valid.
The search stops when a level has more than ``budget`` subsets or when a subset
would keep fewer than ``min_sensors + 1`` readings (nothing left to test).

RECON: the family-wise levels, the trail and the escalating search are ours;
the papers name sensors by a per-sensor chi-square test (notes §2.1 step 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.bank import Chi2Table, cv_matrices, gauss_newton, inv_small, solve_small
from estimators.models import Known, MeasurementModel

MANOEUVRE_MPS2 = 5.0  # white-noise acceleration of the trail: braking or turning hard, as a multirotor can


def _agree_gate(d: int) -> float:
    """Two fits name one position when each lies inside the other's 3-sigma ellipse (99.7 %)."""
    return float(chi2.ppf(0.997, d))


def sidak_gate(alpha: float, p: int) -> float:
    """chi2_1 gate of one of p tests so that all p together fire on clean data with probability ``alpha``."""
    per_test = 1.0 - (1.0 - alpha) ** (1.0 / max(p, 1))
    return float(chi2.ppf(1.0 - per_test, 1))


class Namer:
    """Names readings outside the estimate's support that fail the step or window test (module docstring).

    The window test keeps the raw residuals of the last T steps against each
    step's estimate. Their mean's variance is ``sigma_i^2 / n`` from the noise
    plus up to ``H_i P H_i^T`` from the estimate's own error, which is nearly the
    same over a short window (a filter's error is slow); judging the mean
    against the sum keeps the test at its level instead of counting that shared
    error n times.
    """

    def __init__(self, model: MeasurementModel, alpha: float, window: int = 10) -> None:
        self.model = model
        self.gate = sidak_gate(alpha / 2.0, model.p)
        self.resid = np.zeros((int(window), model.p))
        self.seen = np.zeros((int(window), model.p), dtype=bool)
        self.k = 0

    def name(
        self, z: np.ndarray, pos: np.ndarray, cov_pos: np.ndarray, outside: np.ndarray, known: Known
    ) -> np.ndarray:
        """Feed this step's residuals against ``pos`` to the window; return the readings named (bool, (p,))."""
        hx, jac = self.model.h_jac(pos, known)
        hph = np.einsum("pd,de,pe->p", jac, cov_pos, jac)
        resid = z - hx
        seen = ~np.isnan(resid)
        slot = self.k % self.resid.shape[0]
        self.k += 1
        self.resid[slot] = np.where(seen, resid, 0.0)
        self.seen[slot] = seen
        n = self.seen.sum(axis=0)
        mean = self.resid.sum(axis=0) / np.maximum(n, 1)
        sig2 = self.model.sigma_m**2
        persistent = (n >= 3) & (mean * mean > self.gate * (sig2 / np.maximum(n, 1) + hph))
        jump = np.where(seen, resid * resid > self.gate * (sig2 + hph), False)
        return outside & seen & (jump | persistent)

    def name_jumps(self, z: np.ndarray, pos: np.ndarray, cov_pos: np.ndarray, known: Known) -> np.ndarray:
        """The step test alone, against another fit (the window keeps the estimate's residuals)."""
        hx, jac = self.model.h_jac(pos, known)
        var = self.model.sigma_m**2 + np.einsum("pd,de,pe->p", jac, cov_pos, jac)
        resid = z - hx
        return np.where(np.isnan(resid), False, resid * resid > self.gate * var)


class Trail:
    """Where the vehicle was last known to be, carried forward: the prior an explanation must agree with.

    A constant-velocity Kalman filter on position fixes: set from every valid
    estimate, predicted across the alarm, and corrected by each step's chosen
    explanation, so the explanation a step picks has to continue the last one
    (a coincidental consistent subset metres away does not). Its process noise
    is a manoeuvre, not the estimators' tuning: a multirotor that brakes hard
    (``MANOEUVRE_MPS2``) must stay inside the prior, or a surprised filter
    would look like liars beyond tolerance.
    """

    def __init__(self, d: int, vel_std_mps: float, q_mps2: float = MANOEUVRE_MPS2) -> None:
        self.d, self.q_mps2, self.vel_var = d, q_mps2, vel_std_mps**2
        self.x: np.ndarray | None = None
        self.P = np.eye(2 * d)

    def set(self, pos: np.ndarray, vel: np.ndarray | None, cov: np.ndarray | None) -> None:
        """Restart from an estimate that is valid (its own velocity and covariance where it has them)."""
        d = self.d
        self.x = np.concatenate([pos, np.zeros(d) if vel is None else vel])
        P = np.diag([0.0] * d + [self.vel_var] * d)
        if cov is not None and cov.shape[0] >= 2 * d:
            P = cov[: 2 * d, : 2 * d].copy()
        elif cov is not None:
            P[:d, :d] = cov[:d, :d]
        self.P = P

    def predict(self, dt_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The prior (position, covariance) ``dt_s`` later; None before any valid estimate."""
        if self.x is None:
            return None
        f, q = cv_matrices(self.d, dt_s, self.q_mps2)
        self.x, self.P = f @ self.x, f @ self.P @ f.T + q
        return self.x[: self.d], self.P[: self.d, : self.d]

    def distance(self, pos: np.ndarray, cov: np.ndarray) -> float:
        """Squared Mahalanobis distance of a position (covariance ``cov``) from the predicted trail."""
        if self.x is None:
            return 0.0
        d = self.d
        gap = pos - self.x[:d]
        return float(gap @ np.linalg.solve(self.P[:d, :d] + cov + 1e-12 * np.eye(d), gap))

    def correct(self, pos: np.ndarray, cov: np.ndarray) -> None:
        """Kalman update with a position fix (``H = [I 0]``)."""
        if self.x is None:
            return
        d = self.d
        gain = np.linalg.solve(self.P[:d, :d] + cov, self.P[:d, :]).T
        self.x = self.x + gain @ (pos - self.x[:d])
        self.P = self.P - gain @ self.P[:d, :]


@dataclass(frozen=True, eq=False)
class Explanation:
    """The fewest-liars explanations of one step's readings when more than s lie (module docstring)."""

    liars: int  # k: how many readings the passing subsets leave out (0: nothing passed within the budget)
    named: np.ndarray  # (p,) bool: left out by every passing subset
    pos: np.ndarray | None  # their common position, None if they disagree or none passed
    cov: np.ndarray | None


@dataclass(frozen=True, eq=False)
class Subsets:
    """The subsets that leave out k readings and agree (with each other and, given one, with the prior)."""

    masks: np.ndarray  # (J, p) the hypotheses of this level
    passing: np.ndarray  # (J,) bool
    stat: np.ndarray  # (J,) weighted residual sum (+ prior term)
    pos: np.ndarray  # (J, d) fits
    cov: np.ndarray  # (J, d, d) their covariances

    def best(self) -> int:
        """Index of the passing subset with the smallest statistic (call only when one passes)."""
        idx = np.flatnonzero(self.passing)
        return int(idx[np.argmin(self.stat[idx])])


def agreeing(
    model: MeasurementModel,
    z: np.ndarray,
    k: int,
    chi: Chi2Table,
    start: np.ndarray,
    known: Known,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
    n_iter: int = 6,
) -> Subsets:
    """Fit every subset leaving out k readings; a subset passes when its statistic is under ``chi``.

    With a ``prior`` (position, covariance: the :class:`Trail`), a subset's fit
    must also agree with it: the statistic gains ``(x_S - x0)^T (P0 + C_S)^-1
    (x_S - x0)`` and d degrees of freedom, as in ReCaP's subset score.
    """
    masks = model.honest_subsets(k)
    fits = gauss_newton(model, z, masks, start if prior is None else prior[0], known, n_iter)
    stat, dof = fits.cost, fits.n_used - model.d
    covs = inv_small(fits.info)
    if prior is not None:
        gap = fits.pos - prior[0]
        stat = stat + np.einsum("jd,jd->j", gap, solve_small(prior[1] + covs, gap))
        dof = dof + model.d
    passing = (fits.n_used >= model.min_sensors) & (stat <= chi(dof))
    return Subsets(masks, passing, stat, fits.pos, covs)


def explain(
    model: MeasurementModel,
    z: np.ndarray,
    s: int,
    chi: Chi2Table,
    start: np.ndarray,
    known: Known,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
    n_iter: int = 6,
    budget: int = 2000,
) -> Explanation:
    """Search k = s + 1, s + 2, ... liars for the smallest k that explains ``z`` (module docstring)."""
    p, d = model.p, model.d
    avail = ~np.isnan(z)
    for k in range(s + 1, p):
        if int(avail.sum()) - k < model.min_sensors + 1 or model.honest_subsets(k).shape[0] > budget:
            break
        level = agreeing(model, z, k, chi, start, known, prior, n_iter)
        if not level.passing.any():
            continue
        named = avail & ~np.any(level.masks[level.passing] & avail, axis=0)
        best = level.best()
        spread = level.pos[level.passing] - level.pos[best]
        cov = level.cov[best]
        # The explanations agree on one position when each lies inside the best one's 3-sigma ellipse.
        agree = bool(np.all(np.einsum("jd,de,je->j", spread, np.linalg.pinv(cov), spread) <= _agree_gate(d)))
        return Explanation(k, named, level.pos[best] if agree else None, cov if agree else None)
    return Explanation(0, np.zeros(p, dtype=bool), None, None)

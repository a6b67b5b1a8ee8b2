"""Which readings a secure estimator names as attacked, at a false-alarm level a reader can check.

Every secure estimator decides two things each step: where the vehicle is
(its own algorithm) and which readings it accuses. The second is the same
question for all of them, so it is answered here, once, and a reviewer can
hold each estimator's accusations to the level ``alpha`` it was given.

Within tolerance (no alarm, or an alarm that one step's readings do not confirm)
----------------------------------------------------------------------------
A reading is named only if the output does not rest on it (it is outside
``Estimate.used``) and its residual fails a test. The residuals are taken
against a least-squares fit of the readings the output rests on (a filter's
own estimate lags in a turn, which would make honest readings look biased).
Each step tests p readings, so the tests are a family: every per-reading test
runs at the Sidak level ``a1 = 1 - (1 - alpha / 2)^(1 / p)``, which keeps the
chance that any honest reading is named by it at one step at ``alpha / 2``. Two
tests share the budget:
- the step's own normalised residual ``r_i^2 / (sigma_i^2 + H_i C H_i^T) >
  chi2.ppf(1 - a1, 1)`` (a jump), C the fit's covariance; behind a calibration on real ranges
  (``estimators.noise``) it must fail on ``confirm_steps`` (2) readings of the link in a row, since heavy-tailed
  single spikes are most of what names an honest link there;
- the window test: the mean residual m of the last T steps against its
  variance, ``m^2 > chi2.ppf(1 - a1, 1) (sigma_i^2 + H_i C H_i^T) / n``, the
  current residual leaning the same way (a bias of a few sigma that hides
  inside any single step's gate but not inside the window's mean; see
  :class:`Namer`).
On clean data a step therefore names an honest reading with probability at most
about alpha, whatever p is. (Before this the per-reading gate was
``chi2.ppf(1 - alpha, 1)`` for each of the p readings: eight readings at
alpha = 0.01 named an honest one on 7-9 % of clean steps.)

Beyond tolerance (the alarm is confirmed: no ``p - s`` readings agree)
-------------------------------------------------------------------
Where the vehicle can be is the :class:`Trail`: a constant-velocity tracker of
the valid outputs (corrected by each explanation below while degraded) that
allows a hard manoeuvre. Its prediction is the prior of every test here: a
subset agrees when its fit, with the prior's term added, passes
``chi2.ppf(1 - level, readings used)`` (:func:`agreeing`). An alarm, or an
estimate that leaves the trail (beyond tolerance an estimator's own tests can
accept a coincidental consistent subset far off), is confirmed when no ``p - s``
readings agree at ``alpha / 10``. If some do, the output is theirs whenever the
estimator's own disagrees with them (a least-bad filter after an attack, a
coincidental subset), and stays valid; after the estimator's own alarm its
answer is judged by their fit's covariance alone (a coasting filter's
covariance grows until any answer would "agree"). Then the estimator cannot correct, but it can
still say whom it suspects, and the suspicion should be right. :func:`explain`
is the l0 decoder with a growing budget of liars: for k = s + 1, s + 2, ... it
fits every subset that leaves out k readings (``model.honest_subsets(k)``) and
keeps those that agree at ``alpha``. At the smallest k where
some pass, the readings named are those *every* passing subset leaves out (the
sensors all explanations with the fewest liars agree are lying) that also fail
the within-tolerance tests against the best explanation's fit: with biases of a
few sigma the fewest liars can be honest readings, and the tests keep them from
being accused. Several
explanations that disagree (a colluding attacker who built a second consistent
picture) name only what they share, possibly nothing, and give no position;
a single explanation (or several on one position) also gives its fit, which the
caller outputs *marked degraded* (``Estimate.valid`` False), never as valid.
The search stops when a level has more than ``budget`` subsets or when a subset
would keep fewer than ``min_sensors + 1`` readings (nothing left to test).

RECON: the family-wise levels, the trail and the escalating search are ours;
the sources (estimators/README.md#what-the-sources-allow-us-to-check) do not give the rule;
the usual one is a per-sensor chi-square test at each step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.bank import Chi2Table, cv_matrices, gauss_newton, inv_small, solve_small
from estimators.models import Known, MeasurementModel

MANOEUVRE_MPS2 = 5.0  # white-noise acceleration of the trail: braking or turning hard, as a multirotor can
MAX_SPEED_MPS = 5.0  # the trail's velocity spread before it has seen two fixes


def _agree_gate(d: int) -> float:
    """A fit names the same position as the best one when it lies inside the best one's 3-sigma ellipse."""
    return float(chi2.ppf(0.997, d))


def sidak_gate(alpha: float, p: int) -> float:
    """chi2_1 gate of one of p tests so that all p together fire on clean data with probability ``alpha``."""
    per_test = 1.0 - (1.0 - alpha) ** (1.0 / max(p, 1))
    return float(chi2.ppf(1.0 - per_test, 1))


class Namer:
    """Names readings outside the estimate's support that fail the step or window test (module docstring).

    Residuals are taken against a least-squares fit of this step's supporting
    readings (``used``), not against the estimate itself: a filter's estimate
    lags in a turn and would make honest readings look biased. A reading is
    judged by ``r^2 / (sigma^2 + H C H^T)``, C the fit's covariance. The window
    keeps the raw residuals of the last T steps; each step's fit has its own
    noise, so their mean's variance is ``(sigma^2 + H C H^T) / n`` (against a
    filter's estimate it would not be: its error is shared by nearby steps). A
    reading the window holds
    against must also lean the same way now, so a link whose attack has stopped
    drops out within a step or two instead of after T.
    """

    def __init__(self, model: MeasurementModel, alpha: float, window: int = 10) -> None:
        self.model = model
        self.gate = sidak_gate(alpha / 2.0, model.p)
        self.chi = Chi2Table(alpha, 4 * model.p)
        self.resid = np.zeros((int(window), model.p))
        self.seen = np.zeros((int(window), model.p), dtype=bool)
        self.k = 0
        # This step's residuals (NaN: no reading), for estimators.offsets to follow each link's offset from.
        self.last_resid: np.ndarray | None = None
        # How much larger the window mean's variance is than 1/n of a step's: 1 for errors independent from
        # step to step; estimators.noise sets it from the errors' measured autocorrelation.
        self.window_vif = 1.0
        # Readings in a row a jump must fail before it names the link: 1 on the bench's white noise; estimators.noise
        # sets 2 for real ranges, whose heavy-tailed single spikes (NLOS, multipath) were most of the honest links
        # named once the offsets were followed (estimators/offsets.py).
        self.confirm_steps = 1
        self.jumped = np.zeros(model.p, dtype=int)  # consecutive readings of each link that failed the step test
        # The part of each residual that no honest offset change explains (estimators.offsets.OffsetTracker.beyond);
        # None: all of it. Both tests judge only that part: an offset that moves inside the band is the room, not an
        # attack, and names nobody (it can still be left out of the estimate by the estimator's own tests).
        self.band: Callable[[np.ndarray], np.ndarray] | None = None

    def name(
        self, z: np.ndarray, used: np.ndarray, start: np.ndarray, cov_pos: np.ndarray, known: Known
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Feed this step's residuals to the window: (readings named (bool, (p,)), the reference fit and its
        covariance when the supporting readings agree at alpha, else None, None).

        ``used``: the readings the output rests on; ``start``/``cov_pos``: the
        output, the fallback reference when ``used`` is too few to fit.
        """
        model = self.model
        support = used & ~np.isnan(z)
        agreed = False
        if int(support.sum()) > model.d:
            fit = gauss_newton(model, z, support[None, :], start, known, 2)
            ref, cov, resid, jac = fit.pos[0], inv_small(fit.info[0]), fit.raw[0], fit.jac[0]
            agreed = bool(fit.cost[0] <= self.chi(int(support.sum()) - model.d))
        else:
            ref, cov = start, cov_pos
            hx, jac = model.h_jac(ref, known)
            resid = z - hx
        hcov = np.einsum("pd,de,pe->p", jac, cov, jac)
        seen = ~np.isnan(resid)
        self.last_resid = resid
        if self.band is not None:
            resid = self.band(resid)
        slot = self.k % self.resid.shape[0]
        self.k += 1
        self.resid[slot] = np.where(seen, resid, 0.0)
        self.seen[slot] = seen
        n = self.seen.sum(axis=0)
        mean = self.resid.sum(axis=0) / np.maximum(n, 1)
        sig2 = model.sigma_m**2
        leaning = np.where(seen, resid * mean > 0.0, False)
        persistent = (n >= 3) & leaning & (mean * mean > self.gate * self.window_vif * (sig2 + hcov) / np.maximum(n, 1))
        jump = np.where(seen, resid * resid > self.gate * (sig2 + hcov), False)
        # A missing reading neither confirms nor clears a link's run of failed steps.
        self.jumped = np.where(seen, np.where(jump, self.jumped + 1, 0), self.jumped)
        named = ~used & seen & ((jump & (self.jumped >= self.confirm_steps)) | persistent)
        return (named, ref, cov) if agreed else (named, None, None)


class Trail:
    """Where the vehicle can be: the prior that beyond-tolerance judgements must agree with.

    Its own constant-velocity Kalman filter, corrected each valid step by the
    least-squares fit of the readings the output rests on when they agree (else
    by the output itself, with its own covariance), and while degraded by each
    explanation, so it learns the vehicle's velocity from the fixes rather than
    trusting an estimator's: a snapshot estimator has none, and a filter's
    estimate lags in a turn, which would drag the trail behind the vehicle and
    make the honest readings look like liars. Its process
    noise is a manoeuvre, not the estimators' tuning: a multirotor braking or
    turning hard (``MANOEUVRE_MPS2``) stays inside it, while a coincidental
    consistent subset a metre away in one step does not.
    """

    def __init__(self, d: int, q_mps2: float = MANOEUVRE_MPS2, vel_std_mps: float = MAX_SPEED_MPS) -> None:
        self.d, self.q_mps2, self.vel_var = d, q_mps2, vel_std_mps**2
        self.x: np.ndarray | None = None
        self.P = np.zeros((2 * d, 2 * d))
        self.t_s = 0.0
        self.last_fix: tuple[np.ndarray, np.ndarray] | None = None  # the last position it was corrected with

    def predict_to(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The prior (position, covariance) at ``t_s``; None before the first fix."""
        if self.x is None:
            return None
        dt = max(0.0, t_s - self.t_s)
        if dt > 0.0:
            f, q = cv_matrices(self.d, dt, self.q_mps2)
            self.x, self.P = f @ self.x, f @ self.P @ f.T + q
            self.t_s = t_s
        return self.x[: self.d], self.P[: self.d, : self.d]

    def velocity(self) -> np.ndarray | None:
        return None if self.x is None else self.x[self.d :].copy()

    def hold(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Where to say the vehicle is when nothing explains the readings: the last fix, with the covariance the
        trail has grown since (extrapolating its velocity for seconds would run away from a hovering vehicle)."""
        if self.last_fix is None:
            return None
        d = self.d
        return self.last_fix[0].copy(), self.P[:d, :d].copy()

    def distance(self, pos: np.ndarray, cov: np.ndarray) -> float:
        """Squared Mahalanobis distance of a position (covariance ``cov``) from the predicted trail."""
        if self.x is None:
            return 0.0
        d = self.d
        gap = pos - self.x[:d]
        return float(gap @ np.linalg.solve(self.P[:d, :d] + cov + 1e-12 * np.eye(d), gap))

    def correct(self, pos: np.ndarray, cov: np.ndarray, t_s: float) -> None:
        """Kalman update with a position fix (``H = [I 0]``); the first fix starts the trail at rest."""
        d = self.d
        self.last_fix = (np.array(pos, dtype=float), np.array(cov, dtype=float))
        if self.x is None:
            self.x = np.concatenate([pos, np.zeros(d)])
            self.P = np.zeros((2 * d, 2 * d))
            self.P[:d, :d] = cov
            self.P[d:, d:] = self.vel_var * np.eye(d)
            self.t_s = t_s
            return
        gain = np.linalg.solve(self.P[:d, :d] + cov + 1e-12 * np.eye(d), self.P[:d, :]).T
        self.x = self.x + gain @ (pos - self.x[:d])
        self.P = self.P - gain @ self.P[:d, :]
        self.P = 0.5 * (self.P + self.P.T)


@dataclass(frozen=True, eq=False)
class Explanation:
    """The fewest-liars explanations of one step's readings when more than s lie (module docstring)."""

    named: np.ndarray  # (p,) bool: left out by every passing subset
    pos: np.ndarray | None  # their common position, None if they disagree or none passed
    cov: np.ndarray | None
    used: np.ndarray  # (p,) bool: the readings of the best explanation (none when pos is None)
    tied: bool = False  # several fewest-liars explanations put the vehicle in different places


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
        if int(avail.sum()) - k < model.min_sensors + 1 or model.subset_count(k) > budget:
            break
        level = agreeing(model, z, k, chi, start, known, prior, n_iter)  # honest_subsets is cached
        if not level.passing.any():
            continue
        named = avail & ~np.any(level.masks[level.passing] & avail, axis=0)
        best = level.best()
        spread = level.pos[level.passing] - level.pos[best]
        cov = level.cov[best]
        # The explanations agree on one position when every one lies inside the best one's 3-sigma ellipse.
        agree = bool(np.all(np.einsum("jd,de,je->j", spread, np.linalg.pinv(cov), spread) <= _agree_gate(d)))
        if not agree:
            return Explanation(named, None, None, np.zeros(p, dtype=bool), tied=True)
        return Explanation(named, level.pos[best], cov, level.masks[best] & avail)
    return Explanation(np.zeros(p, dtype=bool), None, None, np.zeros(p, dtype=bool))

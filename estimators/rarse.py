"""``rarse``: RANSAC-style attack-resilient range state estimation (our reading of "RARSE").

Paper: none identified. The seed thesis compares an estimator called RARSE but
no document or code with that name could be found
(estimators/README.md#what-the-sources-allow-us-to-check). We implement the most
defensible reading for range-only localisation: random-sample consensus
over minimal anchor sets, then an EKF on the consensus. Everything here is
RECON.

Model: any ``MeasurementModel``; a hypothesis is fitted from ``min_sensors``
readings (3 ranges in 2-D, 4 in 3-D, one reading of a scalar group).
Attacker: at most ``s`` of p sensors carry arbitrary values (default
``model.max_correctable``); Gaussian noise.

Each step:
1. Hypotheses: a fit on every minimal subset (closed form where the model
   has one: for 2-D anchor ranges, differencing squared horizontal ranges makes
   the three equations linear; else Gauss-Newton, batched), exhaustive when
   there are at most ``max_hypotheses`` of them, else a seeded random sample of
   that many; plus the EKF's prediction.
2. Consensus of hypothesis h: ``I_h = {i : (z_i - h_i(pos_h))^2 <=
   chi2.ppf(1 - alpha, 1) (sigma_i^2 + tau^2)}``, tau the hypothesis' own
   uncertainty (default 2 sigma). Best: the largest consensus, ties by the
   smallest sum of normalised squared residuals over it.
3. I may leave out at most s of the available readings (of each vehicle, in
   the formation: ``model.within_tolerance``); otherwise alarm and coast on
   the prediction.
4. Refit by least squares on I and judge every reading by its studentised
   residual against the refit (a reading in I by its deleted residual
   ``r_i^2 / (sigma_i^2 (1 - l_i))``, leverage ``l_i = H_i C H_i^T / sigma_i^2``;
   one outside by ``r_i^2 / (sigma_i^2 (1 + l_i))``) against chi2_{1, 1-alpha};
   drop the worst failing reading of I and refit, while I keeps more than
   available - s readings (at most s + 1 rounds). The kept set must pass
   ``cost <= chi2.ppf(1 - alpha, |I| - d)`` as a whole, else alarm; then update a constant-velocity EKF with the
   readings of I only. Attacked: readings outside I that fail the tests of ``attribution.py``.
5. Persistent small attacks (RECON, our addition, ``drift.py``): each sensor's
   innovation against the EKF prediction, normalised, goes into a window of T
   steps; a sensor whose window mean m over n readings fails
   ``n m^2 > chi2.ppf(1 - alpha, 1)`` is left out of every consensus (if at
   most s sensors fail) and reported. A single step cannot see a 3-sigma
   bias; the window can.
Defaults: alpha = 0.01, T = 10, tau = 2 sigma, max_hypotheses = 128, q = 0.5 m/s^2.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the hypotheses and the consensus are built from one vector per step, the window's readings brought to
the step's time (window alignment); its EKF then updates once per step with the consensus.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.bank import EkfBank, gauss_newton, inv_small, subset_masks
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.drift import InnovationWindow
from estimators.models import Known, MeasurementModel


class Rarse(Estimator):
    name = "rarse"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(
        self,
        model: MeasurementModel,
        *,
        tau_sigmas: float = 2.0,
        max_hypotheses: int = 128,
        seed: int = 0,
        window: int = 10,
        **params,
    ) -> None:
        self.tau_sigmas = tau_sigmas
        self.window = int(window)
        self.max_hypotheses = int(max_hypotheses)
        self.seed = seed
        super().__init__(model, **params)
        k = min(model.min_sensors, model.p)
        if math.comb(model.p, k) <= self.max_hypotheses:
            self.minimal = subset_masks(model.p, k)
        else:
            rng = np.random.default_rng(seed)
            picks = np.array([rng.choice(model.p, size=k, replace=False) for _ in range(self.max_hypotheses)])
            self.minimal = np.zeros((self.max_hypotheses, model.p), dtype=bool)
            np.put_along_axis(self.minimal, picks, True, axis=1)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.ekf = EkfBank(self.model, np.ones((1, self.model.p), dtype=bool), self.q_axes)
        self.P0 = P0
        self.started = x0 is not None
        self.drift = InnovationWindow(self.model.p, self.window, self.gate1)
        if x0 is not None:
            self.ekf.seed(x0, P0)

    def _consensus(self, z: np.ndarray, pos: np.ndarray, extra_var: np.ndarray, known: Known) -> np.ndarray:
        """Normalised squared residual per (hypothesis, sensor); NaN readings get +inf."""
        resid = z - self.model.h(pos, known)
        t = resid * resid / (self.model.sigma_m**2 + extra_var)
        return np.where(np.isnan(t), np.inf, t)

    def _drifting(self, z: np.ndarray, at_pred: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Sensors whose innovations against the prediction keep one sign over the window (``drift.py``)."""
        d = self.model.d
        return self.drift.update(z, at_pred[0], at_pred[1], self.ekf.P[0][:d, :d], self.model.sigma_m)

    def _eliminate(
        self,
        z: np.ndarray,
        use0: np.ndarray,
        pos: np.ndarray,
        n_iter: int,
        need: int,
        known: Known,
        at_pos: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Backward elimination on the consensus; None if the kept set is inconsistent as a whole."""
        use = use0.copy()
        avail = ~np.isnan(z)
        rounds = sum(k for _, k in self.model.tolerance_groups(self.s)) + 1
        for round_ in range(rounds):  # one reading per round
            first = at_pos if round_ == 0 else None
            refit = gauss_newton(self.model, z, use[None, :], pos, known, n_iter, at_start=first)
            pos, cov = refit.pos[0], inv_small(refit.info[0])
            t = self._studentised(refit.raw[0], refit.jac[0], cov, use)
            worst = int(np.argmax(np.where(use, t, -np.inf)))
            if t[worst] <= self.gate1 or use.sum() <= need:
                break
            use[worst] = False
            if not self.model.within_tolerance(avail & ~use, self.s):  # each group may lose only its tolerance
                use[worst] = True
                break
        # The kept set must be consistent as a whole (a loose consensus can gather a fake position).
        if refit.cost[0] > self.chi(int(use.sum()) - self.model.d):
            return None
        return use, pos, cov, t

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model, d = self.model, self.model.d
        avail = ~np.isnan(z)
        if self.started:
            self.ekf.predict(dt_s)
        start = self.ekf.x[0, :d] if self.started else model.initial_guess(z, known)
        hyps = model.minimal_fixes(z, self.minimal, known)
        if hyps is None:
            # From the prediction a clean minimal set converges in a few steps; cold starts get the full budget.
            hyps = gauss_newton(model, z, self.minimal, start, known, 3 if self.started else self.n_iter).pos
        hyps = np.vstack([hyps, start[None, :]]) if self.started else hyps
        gate = self.gate1
        t = self._consensus(z, hyps, (self.tau_sigmas * model.sigma_m) ** 2, known)
        inlier = t <= gate
        at_pred = model.h_jac(start, known) if self.started else None  # shared by three users below
        drifting = self._drifting(z, at_pred) if at_pred is not None else np.zeros(model.p, dtype=bool)
        if drifting.any() and model.within_tolerance(drifting, self.s):
            inlier &= ~drifting
        size = inlier.sum(axis=1)
        score = np.where(inlier, t, 0.0).sum(axis=1) - 1e12 * size
        best = int(np.argmin(score))
        need = model.min_sensors
        if size[best] < need or not model.within_tolerance(avail & ~inlier[best], self.s):
            return self._coast(t_s)
        # Refit from the prediction (one Gauss-Newton step is noise-level exact there); if that
        # fails, or on a cold start, iterate from the winning hypothesis instead.
        kept = self._eliminate(z, inlier[best], start, 1, need, known, at_pred) if self.started else None
        if kept is None:
            kept = self._eliminate(z, inlier[best], hyps[best], self.n_iter, need, known)
        if kept is None:
            return self._coast(t_s)
        use, pos, cov, t = kept
        if not self.started:
            P0 = self.P0.copy()
            P0[:d, :d] = cov + 1e-6 * np.eye(d)
            self.ekf.seed(np.concatenate([pos, np.zeros(d)]), P0)
            self.started = True
            nis = None
        else:
            self.ekf.masks = use[None, :]
            nis = self.ekf.update(z, known, at_pred)
        x, P = self.ekf.x[0], self.ekf.P[0]
        return self._estimate(t_s, x[:d], x[d:], P, False, use, nis)

    def _coast(self, t_s: float) -> Estimate:
        if not self.started:
            return self._estimate(t_s, None, alarm=True)
        d = self.model.d
        x, P = self.ekf.x[0], self.ekf.P[0]
        return self._estimate(t_s, x[:d], x[d:], P, True)

"""``secopt``: SecOPT, the optimisation (maximum-likelihood) half of SecSens.

Paper: A. Alanwar et al., "SecSens: Secure State Estimation with Application to
Localization and Time Synchronization", arXiv 1801.07132 (abstract only read;
the seed thesis lists it as its Algorithm 3).

Model: any ``MeasurementModel``. Attacker: at most ``s`` of p sensors carry
arbitrary values (default ``s = model.max_correctable``); Gaussian noise.

Equations (RECON; estimators/README.md#what-the-sources-allow-us-to-check).
Under Gaussian noise the maximum-likelihood position
given "the sensors in S are honest" minimises
``J_S(pos) = sum_{i in S} (z_i - h_i(pos))^2 / sigma_i^2``. For every S with
|S| = p - s we solve it by Gauss-Newton (all subsets batched, warm-started at
the previous estimate, at most ``n_iter`` iterations, projected on the model's
box), then sum the minimised costs over a window of the last T steps:
``E_S = sum_t J_S,t``, chi-square with ``sum_t (|S|_t - d)`` dof when S is
clean. Accepted: ``E_S <= chi2.ppf(1 - alpha, dof)``; winner: most readings,
then smallest E_S (the l0 decoder: fewest sensors declared attacked). None
accepted: alarm. Attacked sensors: outside the winner and failing the
tests of ``attribution.py`` (family-wise alpha). The winner's snapshot fix and its covariance
``(H^T W H)^-1`` then update a constant-velocity Kalman filter (position as a
direct measurement), which supplies velocity and smooths the output.

Ties among consistent subsets go to the one with the least accumulated
evidence against it (``subsets.Evidence``, a CUSUM of each step's standardised
cost that is never cleared). RECON: the subset enumeration, the window sum of snapshot costs (we drop the
process-model coupling between the window's states that a full window MLE
would have; the dynamics enter only through the output filter), the dof, the
selection rule and the output filter are ours. Defaults: T = 5, n_iter = 6,
alpha = 0.01.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): every subset fit reads one vector per step, the window's readings brought to the step's time
(window alignment); the window sum of costs then sums aligned steps (a slow link's reading may enter two of them;
the calibration's ``window_vif`` allows for it).
"""

from __future__ import annotations

import numpy as np

from estimators.bank import gauss_newton, inv_small
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel
from estimators.subsets import Evidence, choose


class SecOpt(Estimator):
    name = "secopt"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(self, model: MeasurementModel, *, window: int = 5, **params) -> None:
        self.window = int(window)
        super().__init__(model, **params)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.masks = self.model.honest_subsets(self.s)
        n_sub = self.masks.shape[0]
        self.cost_buf = np.zeros((self.window, n_sub))
        self.dof_buf = np.zeros((self.window, n_sub), dtype=int)
        self.evidence = Evidence(n_sub)
        self.k = 0
        self.P0 = P0
        self.x = None if x0 is None else x0.copy()
        self.P = P0.copy()

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model, d = self.model, self.model.d
        avail = ~np.isnan(z)
        if self.x is not None and dt_s > 0.0:
            f, q = self._cv(dt_s)
            self.x = f @ self.x
            self.P = f @ self.P @ f.T + q
        start = model.initial_guess(z, known) if self.x is None else self.x[:d]
        # Warm start at the prediction: three steps suffice for a clean subset (attacked ones fail anyway).
        fits = gauss_newton(model, z, self.masks, start, known, self.n_iter if self.x is None else 3)
        slot = self.k % self.window
        self.k += 1
        self.cost_buf[slot] = fits.cost
        self.dof_buf[slot] = np.maximum(fits.n_used - d, 0)
        valid = fits.n_used >= model.min_sensors
        evidence = self.evidence.update(np.where(valid, fits.cost, 0.0), np.where(valid, self.dof_buf[slot], 0))
        choice = choose(self.cost_buf.sum(axis=0), self.dof_buf.sum(axis=0), fits.n_used, valid, self.chi, evidence)
        j = choice.index
        use = self.masks[j] & avail
        if not valid[j]:
            return self._coast(t_s, choice.alarm)
        pos, cov = fits.pos[j], inv_small(fits.info[j])
        self._fuse(pos, cov)
        # Subsets that were inconsistent over the window are judged on fresh data after a change
        # (their accumulated evidence stays).
        self.cost_buf[:, ~choice.passing & ~choice.alarm] = 0.0
        self.dof_buf[:, ~choice.passing & ~choice.alarm] = 0
        return self._estimate(t_s, self.x[:d], self.x[d:], self.P, choice.alarm, use)

    def _fuse(self, pos: np.ndarray, cov: np.ndarray) -> None:
        d = self.model.d
        if self.x is None:
            self.x = np.concatenate([pos, np.zeros(d)])
            self.P = self.P0.copy()
            self.P[:d, :d] = cov
            return
        # Kalman update with the fix as a direct position measurement: H = [I 0], R = cov.
        s_mat = self.P[:d, :d] + cov
        gain = np.linalg.solve(s_mat, self.P[:d, :]).T
        self.x = self.x + gain @ (pos - self.x[:d])
        self.P = self.P - gain @ self.P[:d, :]
        self.P = 0.5 * (self.P + self.P.T)

    def _coast(self, t_s: float, alarm: bool) -> Estimate:
        if self.x is None:
            return self._estimate(t_s, None, alarm=alarm)
        d = self.model.d
        return self._estimate(t_s, self.x[:d], self.x[d:], self.P, alarm)

"""``recap``: ReCaP, per-group outlier detection and secure fusion in front of an EKF.

Paper: A. Alanwar, F. Miao, O. Ploder, J. Hespanha, M. B. Srivastava, "ReCaP:
Resilient Cyber Physical Systems Against Adversarial Sensor Attacks"
(submitted to ACM SenSys; not public). The seed thesis names its parts: an
outlier detector (its Alg. 4), "get Omega and initial x0 at i = 0" (Alg. 5) and
a secure estimator per sensor group used when pa > 1 (Alg. 6).

Model: a group of sensors reporting correlated signals. For a ``ScalarGroup``
(the wall distance by lasers, sonar, infrared, radar) that is ReCaP's own
setting; for anchor ranges (and the other models) the whole reading vector is
one group, correlated through the position. Attacker: at most ``pa`` (= s,
default ``model.max_correctable``, i.e. floor((m-1)/2) for a scalar group) of
the group's m sensors carry arbitrary values; Gaussian noise.

Equations, all RECON (the paper could not be read; estimators/README.md#what-the-sources-allow-us-to-check):
- Omega is the set of sensors currently trusted; the state is a constant-velocity
  EKF fed only with Omega's readings.
- Init (Alg. 5, our reading): on the first step, every subset S of m - pa
  sensors is fitted by weighted least squares; the consistent one
  (cost <= chi2_{|S| - d}) with the most readings, then the smallest cost, gives
  Omega_0 and x0. No consistent subset: alarm, try again next step.
- Outlier detector (Alg. 4): against the EKF prediction,
  ``t_i = (z_i - h_i(x-))^2 / (sigma_i^2 + H_i P- H_i^T) > chi2_{1, 1-alpha}``
  flags sensor i.
- pa <= 1: drop the flagged sensors, Omega = the rest. (If more than pa are
  flagged the prediction itself is suspect, so we fall through to the search.)
- pa > 1 (Alg. 6): score every subset S of m - pa sensors by
  ``D_S = sum_{i in S} w_i (z_i - h_i(p_S))^2 + (p_S - p-)^T (P-_pos + C_S)^-1 (p_S - p-)``,
  p_S and C_S its least-squares fit and covariance; for a scalar group this is
  the spread around the inverse-variance mean plus that mean's distance from
  the prediction. Clean S: chi-square with |S| dof. Omega = the accepted S with
  the most readings, then smallest D_S, the previous Omega winning ties.
- The subset fits start at the prediction and take one Gauss-Newton step
  (near the prediction that is already at noise-level precision); only if
  nothing is accepted are they iterated to convergence and judged again.
- Nothing accepted: alarm, coast on the prediction; after ``reinit_after``
  alarmed steps in a row, run the init again (the prediction may be the stale
  part).
- Persistent small attacks (RECON, our addition, shared with rarse,
  ``drift.py``): each sensor's normalised innovation against the prediction
  goes into a window of T steps; a sensor whose window mean fails the chi2_1
  test is kept out of Omega (if at most pa sensors fail). A slowly drifting
  coordinated spoof of a few sigma passes every single-step test; the window
  sees it.
- Attacked: named by ``attribution.py`` as for every secure estimator
  (outside Omega, failing the step or window test at a family-wise alpha).
Defaults: alpha = 0.01, q = 0.5 m/s^2, reinit_after = 5, T = 10.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the detector and its EKF read one vector per step, the window's readings brought to the step's time
(window alignment), so the group's readings are compared at one time.
"""

from __future__ import annotations

import numpy as np

from estimators.bank import EkfBank, gauss_newton, inv_small, solve_small
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.drift import InnovationWindow
from estimators.models import Known, MeasurementModel
from estimators.subsets import choose, secure_snapshot


class Recap(Estimator):
    name = "recap"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(self, model: MeasurementModel, *, reinit_after: int = 5, window: int = 10, **params) -> None:
        self.reinit_after = int(reinit_after)
        self.window = int(window)
        super().__init__(model, **params)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.masks = self.model.honest_subsets(self.s)
        self.ekf = EkfBank(self.model, np.ones((1, self.model.p), dtype=bool), self.q_axes)
        self.P0 = P0
        self.started = x0 is not None
        self.omega = np.ones(self.model.p, dtype=bool)
        self.alarms_in_row = 0
        self.drift = InnovationWindow(self.model.p, self.window, self.gate1)
        if x0 is not None:
            self.ekf.seed(x0, P0)

    def _init(self, z: np.ndarray, known: Known) -> bool:
        fix = secure_snapshot(self.model, z, self.s, self.chi, None, known, self.n_iter)
        if fix.alarm:
            return False
        d = self.model.d
        P0 = self.P0.copy()
        P0[:d, :d] = fix.cov + 1e-6 * np.eye(d)
        self.ekf.seed(np.concatenate([fix.pos, np.zeros(d)]), P0)
        self.omega = fix.use
        self.alarms_in_row = 0
        return True

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        d = self.model.d
        avail = ~np.isnan(z)
        if not self.started:
            self.started = self._init(z, known)
            if not self.started:
                return self._estimate(t_s, None, alarm=True)
            return self._output(t_s, self.omega)
        self.ekf.predict(dt_s)
        x_pred, P_pred = self.ekf.x[0], self.ekf.P[0]
        # h and its Jacobian at the prediction serve the detector, the subset fits' first step and the update.
        at_pred = self.model.h_jac(x_pred[:d], known)
        flagged = self._flag_resid(z - at_pred[0], at_pred[1], P_pred[:d, :d])
        drifting = self.drift.update(z, at_pred[0], at_pred[1], P_pred[:d, :d], self.model.sigma_m)
        if not drifting.any() or not self.model.within_tolerance(drifting, self.s):
            drifting[:] = False  # more than s drifting: the prediction itself has moved, not s sensors
        if self.s <= 1 and (flagged | drifting).sum() <= self.s:
            omega, alarm = avail & ~(flagged | drifting), False
        else:
            omega, alarm = self._search(z, known, x_pred[:d], P_pred[:d, :d], 1, at_pred, drifting)
            if alarm:  # maybe only unconverged: one Gauss-Newton step suffices near the prediction, not far off
                omega, alarm = self._search(z, known, x_pred[:d], P_pred[:d, :d], self.n_iter, at_pred, drifting)
        if alarm:
            self.alarms_in_row += 1
            if self.alarms_in_row >= self.reinit_after and self._init(z, known):
                return self._output(t_s, self.omega)
            x, P = self.ekf.x[0], self.ekf.P[0]
            return self._estimate(t_s, x[:d], x[d:], P, True)
        self.alarms_in_row = 0
        self.omega = omega
        self.ekf.masks = omega[None, :]
        return self._output(t_s, omega, self.ekf.update(z, known, at_pred))

    def _search(
        self,
        z: np.ndarray,
        known: Known,
        pos_pred: np.ndarray,
        cov_pred: np.ndarray,
        n_iter: int,
        at_pred: tuple[np.ndarray, np.ndarray] | None = None,
        drifting: np.ndarray | None = None,
    ) -> tuple[np.ndarray, bool]:
        fits = gauss_newton(self.model, z, self.masks, pos_pred, known, n_iter, at_start=at_pred)
        gap = fits.pos - pos_pred
        # Fit covariance C_S = info^-1; pseudo-inverse keeps rank-deficient subsets finite.
        spread = cov_pred + inv_small(fits.info)
        pred_term = np.einsum("jd,jd->j", gap, solve_small(spread, gap))
        stat = fits.cost + pred_term
        valid = fits.n_used >= self.model.min_sensors
        if drifting is not None and drifting.any():
            valid &= ~(self.masks & drifting).any(axis=1)  # no subset may keep a drifting sensor
        # Previous Omega wins ties: a hair's advantage in the statistic.
        same = np.all(self.masks == self.omega, axis=1)
        choice = choose(stat - 1e-9 * same, fits.n_used, fits.n_used, valid, self.chi)
        return self.masks[choice.index] & ~np.isnan(z), choice.alarm

    def _output(self, t_s: float, omega: np.ndarray, nis: tuple[np.ndarray, np.ndarray] | None = None) -> Estimate:
        d = self.model.d
        x, P = self.ekf.x[0], self.ekf.P[0]
        return self._estimate(t_s, x[:d], x[d:], P, False, omega, nis)

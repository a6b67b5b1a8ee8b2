"""``secekf``: SecEKF, the EKF half of SecSens, as a bank of subset EKFs.

Paper: A. Alanwar, B. Etzlinger, H. Ferraz, J. Hespanha, M. Srivastava,
"SecSens: Secure State Estimation with Application to Localization and Time
Synchronization", arXiv 1801.07132. Only its abstract could be read: two secure
nonlinear estimators (EKF-based and optimisation-based) for noisy systems,
applied to UWB localisation. Template for the bank: Mishra et al., "Secure
state estimation against sensor attacks in the presence of noise", TCNS 2017.

Model: any ``MeasurementModel`` (anchor ranges 2-D/3-D, scalar group, linear,
two vehicles); state ``x = [pos (d), vel (d)]`` with constant-velocity motion.
Attacker: an unknown set of at most ``s`` of the p sensors adds arbitrary
values (any size, sign, coordination); default ``s = model.max_correctable``
(2 of 8 anchors in 2-D). Noise Gaussian with the model's std per sensor.

Equations, everything below RECON (our reconstruction; the paper's algorithm
box was not readable; estimators/README.md#what-the-sources-allow-us-to-check):
1. One EKF per subset S_j of size p - s, J = C(p, p - s) (28 for p = 8, s = 2),
   all seeded from a secure snapshot fix (every subset's least squares, the
   consistent one wins).
2. Each step every filter predicts (F, Q of the CV model) and updates with its
   own sensors only; its normalised innovation squared
   ``eps_j = nu^T (H P H^T + R)^-1 nu`` (dof = readings used) goes into a ring
   buffer of the last T steps.
3. ``E_j = sum of eps_j over the window``; filter j is consistent when
   ``E_j <= chi2.ppf(1 - alpha, sum of dof)``. The winner is the consistent
   filter with the most readings, then the least accumulated evidence (a
   CUSUM of each step's standardised NIS, ``subsets.Evidence``, never cleared),
   then the smallest E_j. No consistent filter:
   alarm (more than s attacked), output the least-bad filter.
4. Attacked sensors: named by ``attribution.py`` as for every secure
   estimator: outside the winner's subset and failing the per-reading step or
   window test at a family-wise level alpha (the complement always has s
   members, even when fewer are attacked).
5. Hygiene: inconsistent filters (they fed on attacked data) are re-seeded from
   the winner with an inflated covariance and their window cleared, so they can
   win again when the attack moves; their accumulated evidence stays, so a
   re-seeded filter does not win a tie against one that was clean all along.
6. Motion input (option ``velocity_std_mps``, ours): after each prediction every filter reads the vehicle's own
   velocity estimate as a measurement of its velocity state, so a filter cannot explain a drift of the readings
   by a velocity the vehicle does not report (``bank.EkfBank.update_velocity``).
Defaults: alpha = 0.01, T = 10 steps, q = 0.5 m/s^2, no motion input. The full bank runs every
step (no "lazy" single-filter mode), vectorised over subsets.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the bank reads one vector per step, the window's readings brought to the step's time (window
alignment), not each reading at its own time: the subset test compares readings of one time. Its NIS window sums
steps; a link read more slowly than the steps is used again at the next step, and the calibration's ``window_vif``
(fitted on the aligned stream) allows for the correlation that makes.
"""

from __future__ import annotations

import numpy as np

from estimators.bank import EkfBank
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel
from estimators.subsets import Evidence, choose, secure_snapshot


class SecEkf(Estimator):
    name = "secekf"
    tuned_on = TUNED_ON_BUNDLED
    secure = True
    motion_input = True

    def __init__(self, model: MeasurementModel, *, window: int = 10, reseed_inflation: float = 2.0, **params) -> None:
        self.window = int(window)
        self.reseed_inflation = reseed_inflation
        super().__init__(model, **params)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.masks = self.model.honest_subsets(self.s)
        self.bank = EkfBank(self.model, self.masks, self.q_axes)
        n_sub = self.masks.shape[0]
        self.nis_buf = np.zeros((self.window, n_sub))
        self.dof_buf = np.zeros((self.window, n_sub), dtype=int)
        self.evidence = Evidence(n_sub)
        self.k = 0
        self.P0 = P0
        self.started = x0 is not None
        if x0 is not None:
            self.bank.seed(x0, P0)

    def _start(self, z: np.ndarray, known: Known) -> bool:
        fix = secure_snapshot(self.model, z, self.s, self.chi, None, known, self.n_iter)
        if fix.alarm:
            return False
        d = self.model.d
        P0 = self.P0.copy()
        P0[:d, :d] = fix.cov + 1e-6 * np.eye(d)
        self.bank.seed(np.concatenate([fix.pos, np.zeros(d)]), P0)
        return True

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        d = self.model.d
        avail = ~np.isnan(z)
        if not self.started:
            self.started = self._start(z, known)
            if not self.started:
                return self._estimate(t_s, None, alarm=True)
        else:
            self.bank.predict(dt_s)
            self._motion(self.bank)
        innovation = self.bank.update(z, known)
        nis, dof = innovation
        slot = self.k % self.window
        self.k += 1
        self.nis_buf[slot] = nis
        self.dof_buf[slot] = dof
        stat, total_dof = self.nis_buf.sum(axis=0), self.dof_buf.sum(axis=0)
        finite = np.all(np.isfinite(self.bank.x), axis=1)
        evidence = self.evidence.update(np.where(finite, nis, 0.0), np.where(finite, dof, 0))
        choice = choose(stat, total_dof, dof, finite & (dof >= self.model.min_sensors), self.chi, evidence)
        j = choice.index
        x, P = self.bank.x[j].copy(), self.bank.P[j].copy()
        use = self.masks[j] & avail
        if not choice.alarm:
            stale = ~choice.passing | ~finite
            if stale.any():
                self.bank.seed(x, self.reseed_inflation * P, stale)
                self.nis_buf[:, stale] = 0.0
                self.dof_buf[:, stale] = 0
        return self._estimate(t_s, x[:d], x[d:], P, choice.alarm, use, innovation, j)

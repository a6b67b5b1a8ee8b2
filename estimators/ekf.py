"""``ekf``: constant-velocity extended Kalman filter on all readings, the undefended baseline.

Paper: none (textbook EKF, as in FilterPy's ``ExtendedKalmanFilter``).
Model: any ``MeasurementModel``; state ``x = [pos (d), vel (d)]``.
Attacker: none assumed; biased readings pull the state along, which the
property tests and the benchmark show.

Predict ``x <- F x``, ``P <- F P F^T + Q`` with ``F = [[I, dt I], [0, I]]``,
``Q = q^2 G G^T``, ``G = [dt^2/2 I; dt I]`` (white acceleration of std q).
Update with every reading present: ``nu = z - h(pos)``, ``H = [dh/dpos, 0]``,
gain form ``K = P H^T (H P H^T + R)^-1``, ``x+ = x- + K nu``, ``P+ = P- - K H P-``,
computed with d x d algebra only (push-through identity; see ``bank.EkfBank``). The first step, without ``x0``,
starts from a least-squares fix of the first readings. With ``velocity_std_mps`` the vehicle's own velocity
(``step(..., velocity=)``) updates the velocity state after each prediction (``bank.EkfBank.update_velocity``).

Asynchronous readings (``async_window_s``, estimators.aligned: sequential updates; the default on recorded ranges and
in the secure stage): ``step`` takes any subset of the readings (NaN = not read) at the time given, so the filter
takes readings one at a time, each at its own timestamp (predict to the reading's time, update with it; readings
sharing a timestamp are one update; one older than the filter's time is brought forward with the motion model), and
its output at an output time is its prediction to that time (``step(t, all NaN)``). Framed (``--sync``), it reads
one vector of readings per frame as if taken together.
"""

from __future__ import annotations

import numpy as np

from estimators.bank import EkfBank
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known


class ExtendedKalman(Estimator):
    name = "ekf"
    tuned_on = TUNED_ON_BUNDLED
    motion_input = True
    sequential = True

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.bank = EkfBank(self.model, np.ones((1, self.model.p), dtype=bool), self.q_axes)
        self.started = x0 is not None
        self.P0 = P0
        if x0 is not None:
            self.bank.seed(x0, P0)

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        d = self.model.d
        avail = ~np.isnan(z)
        if not self.started:
            if avail.sum() < self.model.min_sensors:
                return self._estimate(t_s, None, used=avail)
            pos, cov, _ = self._snapshot_fix(z, avail, None, known)
            P0 = self.P0.copy()
            P0[:d, :d] = cov + 1e-6 * np.eye(d)
            self.bank.seed(np.concatenate([pos, np.zeros(d)]), P0)
            self.started = True
            nis = None
        else:
            self.bank.predict(dt_s)
            self._motion(self.bank)
            nis = self.bank.update(z, known)
        x, P = self.bank.x[0], self.bank.P[0]
        return self._estimate(t_s, x[:d], x[d:], P, used=avail, nis=nis)

"""``ls``: Gauss-Newton multilateration, the undefended snapshot baseline.

Paper: none (textbook nonlinear least squares, e.g. Foy 1976 "Position-location
solutions by Taylor-series estimation"). Model: any ``MeasurementModel``; on
anchor ranges this is multilateration, on a scalar group the inverse-variance
weighted mean. Attacker: none assumed; a single bad reading moves the fix
without bound, which is why it is a baseline.

Each step, from the previous fix (or the model's starting point), iterate
``pos <- pos + (H^T W H)^-1 H^T W (z - h(pos))`` with ``W = diag(1/sigma_i^2)``
over the readings present (NaN readings are left out), projected on the
model's box. Covariance ``(H^T W H)^-1``. With fewer readings than the model
needs the previous fix is held. Never reports attacked sensors or alarms.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): one fix per output time from the window's readings brought to that time (window alignment): a reading taken
before the output is moved by the motion the trusted links' track says, so the fix is of one time, not of a frame's
readings of different ages.
"""

from __future__ import annotations

import numpy as np

from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known


class LeastSquares(Estimator):
    name = "ls"
    tuned_on = TUNED_ON_BUNDLED

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        d = self.model.d
        self.pos = None if x0 is None else x0[:d].copy()
        self.cov = P0[:d, :d].copy()

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        avail = ~np.isnan(z)
        if avail.sum() >= self.model.min_sensors:
            self.pos, self.cov, _ = self._snapshot_fix(z, avail, self.pos, known)
        return self._estimate(t_s, self.pos, cov=self.cov, used=avail)

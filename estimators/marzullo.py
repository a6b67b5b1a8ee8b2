"""``marzullo``: interval fusion for a group of sensors that measure one quantity.

Paper: K. Marzullo, "Tolerating failures of continuous-valued sensors", ACM TOCS
1990; in the attack setting R. Ivanov, M. Pajic, I. Lee, "Attack-resilient sensor
fusion", DATE 2014. The natural baseline for ReCaP's wall group: no dynamics, no
distribution, only intervals.

Model: a ``ScalarGroup`` (m sensors measuring one distance). Each reading
becomes the interval ``[z_i - k sigma_i, z_i + k sigma_i]`` that holds the true
value when sensor i is honest (``k = sqrt(chi2_{1, 1-alpha})``, so each honest
interval misses the truth with probability alpha). Attacker: at most ``f = s``
of the m sensors (default ``floor((m - 1) / 2)``), arbitrary values.

Equations. Sweep the interval end points in order: the set of points covered by
at least ``m - f`` intervals must contain the truth. The fused interval is the
smallest interval holding all such points (Marzullo's fusion interval); the
estimate is its midpoint and its width the guaranteed error bound. No point is
covered by ``m - f`` intervals: more than f sensors lie, alarm, and the
previous estimate is kept (degraded). Attacked: sensors whose interval does not
meet the fused interval and that fail the tests of ``attribution.py``. Missing
readings shrink m. Defaults: alpha = 0.01.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the intervals are drawn around one vector per step, the window's readings brought to the step's
time (window alignment).
"""

from __future__ import annotations

import numpy as np

from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel, ScalarGroup


class Marzullo(Estimator):
    name = "marzullo"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    @classmethod
    def applies_to(cls, model: MeasurementModel) -> bool:
        return isinstance(model, ScalarGroup)

    def __init__(self, model: MeasurementModel, **params) -> None:
        if not self.applies_to(model):
            raise ValueError(f"marzullo fuses a group of sensors measuring one quantity, not a {type(model).__name__}")
        super().__init__(model, **params)
        self.k = float(np.sqrt(self.gate1))

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.pos = None if x0 is None else x0[:1].copy()

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        avail = ~np.isnan(z)
        m = int(avail.sum())
        need = m - self.s
        if m == 0 or need < 1:
            return self._estimate(t_s, self.pos, alarm=m > 0, used=avail)
        half = self.k * self.model.sigma_m
        lo, hi = z - half, z + half
        fused = fusion_interval(lo[avail], hi[avail], need)
        if fused is None:
            return self._estimate(t_s, self.pos, alarm=True, used=avail)
        a, b = fused
        self.pos = np.array([(a + b) / 2.0])
        cov = np.array([[((b - a) / 2.0) ** 2 / self.gate1 + 1e-12]])  # the half-width as k standard deviations
        meets = avail & (hi >= a) & (lo <= b)
        return self._estimate(t_s, self.pos, cov=cov, used=meets)


def fusion_interval(lo: np.ndarray, hi: np.ndarray, need: int) -> tuple[float, float] | None:
    """The smallest interval holding every point covered by at least ``need`` of ``[lo_i, hi_i]``; None if none is."""
    events = sorted([(float(v), 0) for v in lo] + [(float(v), 1) for v in hi])  # opens sort before closes
    depth, first, last = 0, None, None
    for value, kind in events:
        if kind == 0:
            depth += 1
            if depth >= need and first is None:
                first = value
        else:
            if depth >= need:
                last = value
            depth -= 1
    return None if first is None or last is None else (first, last)

"""Never unsafe: the positions the anchors' geometry and a motion bound allow, and what a step outside them means.

Every estimator's output on a model with an admissible box (``model.bounds_m``: anchor ranges in the plane or in
space, the formation) is held to an envelope:

- **Geometry.** The position lies in the model's box (the anchors' horizontal box widened by 20 % of its larger
  side, ``models._anchor_box``, and in space the heights the model admits: down to the ground with the laser),
  widened by ``slack_m`` for the noise of a fix at its edge (a vehicle on the ground reads a little below it).
  Beyond that no reading of the model's can place the vehicle, and a filter there has diverged.
- **Motion.** Each coordinate of the position moves at most ``max_speed_mps`` per second since the last output
  that was claimed valid, plus ``slack_m`` for the noise of two fixes: ``|x_i - v_i| <= max_speed_mps (t - t_v) +
  slack_m``. The defaults (10 m/s, 1 m) are above what the bench's vehicles do (the moving leg swings at 0.5 m/s;
  PX4's default horizontal speed limit is 12 m/s over both axes, at most 8.5 m/s per axis on a diagonal) and
  above a fix's scatter at the stated noise (0.1 m, geometric dilution of 2-3), so a clean run never touches the
  bound. It is an outer fence, not a detector: a drift slower than the bound passes it.
- **Knowing where it is.** A filter whose position covariance says it no longer knows (the largest position
  standard deviation above half the box's largest side, or a covariance that is not finite) has diverged too:
  after a long gap its coasting prediction is not an estimate.

A step that claims valid but lies outside the envelope, or whose filter has lost track, is reported on the
envelope (:meth:`Envelope.project`, the nearest allowed point per coordinate), with ``alarm`` set, ``valid``
False and ``reinitialised`` True, and the estimator is re-initialised (``Estimator.reset``: it starts again
from the next readings, as at the first step); the last valid position and its time are kept, so the bound
keeps growing from there. A step its estimator already marked degraded (beyond tolerance) is only held inside
the envelope (and its alarm set): its large covariance is honest, and a restart would throw away the trail
and the evidence of the attack it is in the middle of. Models without a box (a scalar group, a linear
model) have no geometry to bound and are left as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.models import MeasurementModel

MAX_SPEED_MPS = 10.0
SLACK_M = 1.0


@dataclass
class Envelope:
    lo: np.ndarray  # the model's box, widened by slack_m
    hi: np.ndarray
    max_speed_mps: float = MAX_SPEED_MPS
    slack_m: float = SLACK_M
    last_pos: np.ndarray | None = None  # the last position claimed valid
    last_t: float | None = None

    @classmethod
    def of(cls, model: MeasurementModel, max_speed_mps: float, slack_m: float) -> Envelope | None:
        """The envelope of ``model`` (None without an admissible box)."""
        if not max_speed_mps > 0 or not slack_m >= 0:
            raise ValueError(f"max_speed_mps={max_speed_mps} must be positive and motion_slack_m={slack_m} "
                             "not negative")  # fmt: skip
        if model.bounds_m is None:
            return None
        lo, hi = (np.asarray(b, dtype=float).reshape(-1) for b in model.bounds_m)
        return cls(lo - slack_m, hi + slack_m, float(max_speed_mps), float(slack_m))

    @property
    def max_spread_m(self) -> float:
        """The position standard deviation above which a filter no longer knows where it is (half the box)."""
        return 0.5 * float(np.max(self.hi - self.lo))

    def bounds(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The allowed box at ``t_s``: the geometry's, cut to the motion bound around the last valid position."""
        if self.last_pos is None or self.last_t is None:
            return self.lo, self.hi
        reach = self.max_speed_mps * max(0.0, t_s - self.last_t) + self.slack_m
        return np.maximum(self.lo, self.last_pos - reach), np.minimum(self.hi, self.last_pos + reach)

    def allows(self, pos: np.ndarray, t_s: float) -> bool:
        lo, hi = self.bounds(t_s)
        return bool(np.isfinite(pos).all() and np.all(pos >= lo) and np.all(pos <= hi))

    def project(self, pos: np.ndarray, t_s: float) -> np.ndarray:
        """The nearest allowed point, coordinate by coordinate (the last valid position if ``pos`` is not finite)."""
        lo, hi = self.bounds(t_s)
        if not np.isfinite(pos).all():
            return (0.5 * (lo + hi)) if self.last_pos is None else self.last_pos.copy()
        return np.minimum(np.maximum(pos, lo), hi)

    def lost(self, cov: np.ndarray | None, d: int) -> bool:
        """Whether a filter's covariance says it no longer knows where it is (module docstring)."""
        if cov is None:
            return False
        block = np.asarray(cov, dtype=float)[:d, :d]
        if not np.isfinite(block).all():
            return True
        return float(np.sqrt(max(float(np.max(np.diag(block))), 0.0))) > self.max_spread_m

    def accept(self, pos: np.ndarray, t_s: float) -> None:
        """Record a valid output: the motion bound grows from here."""
        self.last_pos, self.last_t = np.array(pos, dtype=float), float(t_s)

"""Per-link offsets followed online, within a drift bound a slow ramp cannot hide under.

A calibration window (``estimators.noise``) learns each link's offset once. On real two-way UWB ranges the
offset is not constant: it depends on where the tag is and how it is turned (LIAS-CUHKSZ mid run, tag 0: the
10 s medians of one link's error move by 0.1-0.2 m over two minutes, 2-4 times the calibrated sigma, at about
0.01 m/s; estimators/README.md, "Real noise"). The naming tests then accuse honest links on half of the clean
steps. Following the offsets online removes that, and would also follow an attacker's slow ramp, so the
tracker is held to three bounds:

- **Time constant** ``tau_s``: each step the offset moves by ``dt / tau_s`` of the link's residual (an
  exponentially weighted mean of the residuals), so it follows the seconds-to-minutes changes of the room, not
  a step's noise.
- **Rate bound** ``rate_mps``: it moves at most ``rate_mps * dt`` per step, whatever the residual. A ramp
  faster than that outruns it and the gap grows at (ramp - rate_mps) until the naming tests see it.
- **Drift bound** ``bound_m``: it never leaves the calibrated offset by more than ``bound_m``. A ramp slower
  than the rate bound is absorbed up to ``bound_m`` and no further: from there on all of it shows in the
  residual, so any ramp, however slow, is named by the time it exceeds ``bound_m`` plus the naming tests'
  margin (``attribution.Namer``: about 3.4 sigma for one step, 2.6 sigma with the window's correlation).

It learns only from what it can vouch for: a step claimed valid without an alarm, and per link only readings
that are not named now and were not named in the evidence window (``base.EVIDENCE_STEPS``). A named link's
offset is frozen, so an attack that was caught cannot be learnt while it lasts. The residuals are those the
naming tests use (``Namer.last_resid``: against the least-squares fit of the readings the output rests on).

What it costs, plainly: an attacker who stays under the rate bound can move each link by ``bound_m`` without
being named, and the position by what ``bound_m`` on the attacked links buys (at most the l0 bound of
``estimators.bounds`` for a box of ``bound_m``), as an honest offset change of that size would.
RECON: the bounds and the rule are ours, chosen on the LIAS-CUHKSZ development split (README).
"""

from __future__ import annotations

import numpy as np

TAU_S = 10.0  # the offsets of the room change over tens of seconds
RATE_MPS = 0.02  # twice the fastest honest change measured (0.01 m/s), a fifth of the 0.1 m/s ramp to catch
BOUND_M = 0.25  # the largest honest excursion from the window's offset measured (0.2 m) plus a margin


class OffsetTracker:
    """Follows each link's offset from the naming tests' residuals (module docstring)."""

    def __init__(self, p: int, tau_s: float = TAU_S, rate_mps: float = RATE_MPS, bound_m: float = BOUND_M) -> None:
        if not (tau_s > 0 and rate_mps >= 0 and bound_m >= 0):
            raise ValueError(f"offset tracking: tau_s={tau_s} must be positive, rate_mps={rate_mps} and "
                             f"bound_m={bound_m} not negative")  # fmt: skip
        self.tau_s, self.rate_mps, self.bound_m = float(tau_s), float(rate_mps), float(bound_m)
        self.delta = np.zeros(p)  # added to the calibrated offsets
        self.most = np.zeros(p)  # the largest |delta| each link has reached
        self.t_s: float | None = None

    def update(self, t_s: float, resid: np.ndarray | None, trusted: np.ndarray) -> None:
        """Learn from this step's residuals of the corrected readings (NaN: none) on the ``trusted`` links."""
        dt = 0.0 if self.t_s is None else max(0.0, float(t_s) - self.t_s)
        self.t_s = float(t_s)
        if resid is None or dt <= 0.0:
            return
        ok = trusted & np.isfinite(resid)
        step = np.clip(np.where(ok, resid, 0.0) * min(1.0, dt / self.tau_s), -self.rate_mps * dt, self.rate_mps * dt)
        self.delta = np.clip(self.delta + step, -self.bound_m, self.bound_m)
        self.most = np.maximum(self.most, np.abs(self.delta))

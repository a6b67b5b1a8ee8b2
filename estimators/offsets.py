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

Naming: the band
----------------
An honest offset does not only drift: it can also move 0.1-0.3 m within a second or two and come back after a few
seconds (LIAS mid, tag 0: link 15 read 0.22-0.31 m short of the fit for 6 s), as fast as the ramp to catch. The
tracker must not follow that (its rate bound is what names the ramp), and while it does not, the naming tests saw
4-7 sigma and named the link on every step of the episode: the honest links named on 4-7 % of the clean steps of
that run. So the naming tests judge only what no honest offset explains: :meth:`OffsetTracker.beyond` takes each
residual back to the window's offset and keeps only its excess over a band of ``band_m`` (default the drift
bound: one assumption, an honest offset stays within ``bound_m`` of the window's, used twice). Inside the band a
reading names nobody, however fast it got there (the estimator's own tests may still leave it out of the
estimate); beyond it both tests (two failed readings in a row, the window's mean) judge the excess as before.
The band is fixed about the window's offset, so the tracker cannot carry it along after an attacker's ramp.

What it costs, plainly: an attacker can move any link by up to ``band_m`` plus the tests' margin from the window's
offset (on LIAS 0.25 m plus about 0.2 m), at any speed and for as long as they like, without it being named; before
the band a jump of that size was named within two readings and only a ramp under the rate bound got as far. On the
LIAS tuning tags a constant bias on one link is named on every attacked step from 0.8 m (before: 0.5 m), at 0.3 m on
at most 18 % (docs/recorded-ranges.md, "After the window"). How far
that moves the estimate is bounded separately: the readings are corrected by the tracked offset, which follows an
unnamed attacker at most ``rate_mps`` and never past ``bound_m``; what is left the estimator's own tests see
or do not (at most the l0 bound of ``estimators.bounds`` for a box of ``band_m`` plus the margin, as an honest
offset change of that size would). A 0.1 m/s ramp is now named at 0.4-0.6 m instead of 0.2-0.4 m.
RECON: the bounds, the band and the rule are ours; the bounds were chosen on the LIAS-CUHKSZ development split,
the band on tags 1 and 2 only (scripts/naming_sweep.py, estimators/README.md "Real noise").
"""

from __future__ import annotations

import numpy as np

TAU_S = 10.0  # the offsets of the room change over tens of seconds
RATE_MPS = 0.02  # twice the fastest honest change measured (0.01 m/s), a fifth of the 0.1 m/s ramp to catch
BOUND_M = 0.25  # the largest honest excursion from the window's offset measured (0.2 m) plus a margin
BAND_M = 0.25  # naming: an offset this near the window's is the room, not an attack (scripts/naming_sweep.py)


class OffsetTracker:
    """Follows each link's offset from the naming tests' residuals (module docstring)."""

    def __init__(
        self,
        p: int,
        tau_s: float | None = None,
        rate_mps: float | None = None,
        bound_m: float | None = None,
        band_m: float | None = None,
    ) -> None:
        # None: the module's constants, read now (scripts/naming_sweep.py varies them).
        tau_s = TAU_S if tau_s is None else tau_s
        rate_mps = RATE_MPS if rate_mps is None else rate_mps
        bound_m = BOUND_M if bound_m is None else bound_m
        band_m = max(BAND_M, bound_m) if band_m is None else band_m
        if not (tau_s > 0 and rate_mps >= 0 and bound_m >= 0 and band_m >= bound_m):
            raise ValueError(f"offset tracking: tau_s={tau_s} must be positive, rate_mps={rate_mps} and "
                             f"bound_m={bound_m} not negative, band_m={band_m} at least bound_m")  # fmt: skip
        self.tau_s, self.rate_mps, self.bound_m = float(tau_s), float(rate_mps), float(bound_m)
        self.band_m = float(band_m)
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

    def beyond(self, resid: np.ndarray) -> np.ndarray:
        """The part of each residual (of readings corrected by the tracked offsets; NaN: none) that no offset within
        ``band_m`` of the window's explains: 0 inside the band, else its excess over the band, signed."""
        window = resid + self.delta  # the residual against the window's offset
        return window - np.clip(window, -self.band_m, self.band_m)

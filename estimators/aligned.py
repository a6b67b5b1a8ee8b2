"""Readings one at a time, each with its own timestamp: the estimators' asynchronous input (issue 34).

Real ranges arrive one link at a time and at uneven rates. Framing them into synchronous steps hands an estimator
readings of different ages as if taken together; with a vehicle moving at 0.5 m/s a 1 s old reading is 0.5 m off.
Every estimator can instead take readings with their own times, through one of two wrappers with the same shape:

- ``read(t_s, z, known=None)``: readings taken at ``t_s`` (``z`` (p,), NaN = not read then); no output;
- ``step(t_s, z=None, known=None, velocity=None, times=None)``: take ``z`` (each reading at ``times[i]``, else at
  ``t_s``) and give the estimate at ``t_s``, an ``Estimate`` as ``Estimator.step`` gives.

**Sequential updates** (:class:`Sequential`; estimators whose class says ``sequential = True``: the EKF). Every
reading updates the filter at its own time: predict to the reading's time, update with it (readings sharing a
timestamp are one update); the output at ``t_s`` is the prediction to ``t_s``. This is the standard treatment of
asynchronous measurements in a Kalman filter (sequential processing; Bar-Shalom, Li, Kirubarajan, *Estimation with
Applications to Tracking and Navigation*, Wiley 2001). A reading older than the filter's time (out of order) is
first brought to the filter's time as below, then applied there. Until the filter has a first estimate it starts
from the window's aligned readings (a tag that polls one anchor at a time never has a fix's readings at one time).

**Window alignment** (:class:`Aligned`; every other estimator: LS, SecEKF, SecOPT, ReCaP, RARSE, l1, l0, MILP,
poly, Marzullo, plugins). The subset and secure methods test one vector of readings per step against each other
(which p - s agree), so they need readings of one time. A sliding window keeps the readings of the last
``window_s`` seconds; at an output time t each link's readings in ``(t - window_s, t]`` are brought to t with the
constant-velocity motion model and the link's reading at t is their mean (the readings that arrived since the last
output; a link with none is represented by its newest reading in the window, used again, brought to t as well;
the default window below is long enough that every link has one). Bringing a range to
another time is time registration ("time alignment") of asynchronous sensors before fusion, by prediction with the
target's motion model (W. D. Blair, T. R. Rice, B. S. McDole, E. M. Sproul, "Least-squares approach to
asynchronous data fusion", Proc. SPIE 1697, 1992; Bar-Shalom et al. 2001, same chapter as above). For a range the
prediction is exact under constant velocity:

    z_i(t) = z_i(t_i) + h_i(p) - h_i(p - v (t - t_i))

with ``p`` the position at t and ``v`` the velocity: from the vehicle's own velocity when it reports one (the motion
input, ``velocity=``), else from a track: a constant-velocity EKF (the estimator's process noise) that takes the raw
readings one at a time, each at its own time, but only those of the links the last valid output rested on
(``Estimate.used``: the readings the secure method trusted), seeded at that output. Why not a track of the outputs
themselves: the outputs come from the aligned readings, so a velocity error moves the readings, the readings move the
output and the output the velocity, a loop that diverged (a hovering tag polled one anchor at a time, a 2.5 s window:
LS went 5 m off within 10 s); the readings' own track has no such loop. An attacked link the output left out does
not move the track; one it trusted (an attack within the noise) moves it no more than it moves the output. Until
the first valid output, and when the track has not been corrected for more than two windows (at least 1 s; after a
gap, or while an attack beyond tolerance degrades the output), the readings go in unaligned: a velocity extrapolated
that far would move them by what the estimator no longer knows and keep it from coming back (measured: SecEKF after
a 7 s gap). RECON: the choice of the mean over a link's readings, the reuse of a link's newest reading, the track
and the staleness rule are ours.

**The default window** (:func:`default_window`; ``secuav-eval --ranges`` and a study's recordings without
``--window``/``window_s``): one output period, or, when a link is read more slowly than the outputs, the 90th
percentile of the slowest link's reading intervals (``COVER_QUANTILE``), so that every window holds a reading of
every link that reads at all. Why: a tag that polls its anchors one after another at the start of each output
period (the Hanyang outdoor recordings: four links, each cycle starting on the 0.1 s output grid) puts the reading
of the link polled first one period, to the last bit, before the next output; a window of exactly one period (the
old default) left that link out of 40 % of the outputs (an output period from the median spacing of the output
times comes out a few ulp under 0.1 s), and least squares, with one range to spare on those, went from 0.71 m
(framed) to 2.65 m RMSE on LOS case 4. With the covering window (0.102 s there) each output holds all four links,
the link read first represented by its reading of one period ago, used again and brought to the output time. A link
read more seldom than ``COVER_MAX_S`` (1 s) is not covered by default: the window stays one period and the refusal
below names the link and the window it needs (a window that long reuses one reading at many outputs; give it
explicitly). RECON: the 90th percentile and the 1 s bound are ours; time registration does not prescribe a window.
The other half of the Hanyang loss was not the window: after the envelope restarted an estimator (a step beyond
the motion bound, estimators.envelope), its next cold fix searched from amid the anchors, and with the tag 10-28 m
outside a 5 m anchor box the ranges' near-mirror image across the anchors won that search and held (least squares
and the EKF 10-18 m off for 4-7 s, in either processing; a few more three-link outputs asynchronously made it
happen there). A restart now searches from the last position claimed valid (``Estimator.restart_pos``), which the
vehicle is within the motion bound of and its mirror image is not.

What the alignment cannot do, honestly: it moves a reading by the motion the estimator believes, so an error of that
velocity ``dv`` leaves ``dv (t - t_i)`` in the reading (a reading 1 s old with the velocity 0.1 m/s off: 0.1 m). It
is bounded by what a secure output says, never by the readings' own claim; an attacker can move it only as far as
he moves the secure estimate. A reading used again at the next step (a link read more slowly than the outputs)
makes consecutive steps share its error: the window tests then see correlated residuals, which the calibration's
``window_vif`` (estimators.noise, fitted on the aligned stream) measures; without a calibration the window tests
assume independent steps. Give a window no longer than the slowest link needs (``coverage``/``refusal`` below).
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.base import Estimate, Estimator
from estimators.ekf import ExtendedKalman
from estimators.models import Known, MeasurementModel
from estimators.registry import create as create_registered
from estimators.registry import get as get_class

ASYNC_PARAM = "async_window_s"  # estimators.create parameter: wrap the estimator for asynchronous readings
STALE_WINDOWS, STALE_MIN_S = 2.0, 1.0  # no alignment when the last valid output is older than 2 windows (1 s at least)
MIN_LINK_SHARE = 0.5  # a link that reads at all must have a reading in at least this share of the output windows
MIN_FIX_SHARE = 0.5  # at least this share of the outputs must hold the readings a fix needs
COVER_QUANTILE = 0.9  # the default window covers this quantile of the slowest link's reading intervals ...
COVER_MAX_S = 1.0  # ... if at most this; a link read more seldom is refused unless a window is given (``refusal``)


class _Window:
    """Per link, the time-stamped readings of the last ``window_s`` seconds (in time order, duplicates dropped)."""

    def __init__(self, p: int, window_s: float) -> None:
        self.window_s = window_s
        self.t: list[list[float]] = [[] for _ in range(p)]
        self.v: list[list[float]] = [[] for _ in range(p)]
        self.used_until = np.full(p, -math.inf)  # the newest reading of each link an output has used
        self.readings = 0  # taken
        self.late = 0  # older than the window at the time they arrived: dropped
        self.reused = 0  # link-steps that used a reading already used by an earlier output
        self.newest = -math.inf  # the latest time seen (a reading's or an output's)

    def add(self, t_s: float, z: np.ndarray) -> np.ndarray:
        """Keep the finite readings of ``z`` taken at ``t_s``; returns which of them were new (not a repeat of a
        reading already held, not older than the window)."""
        self.newest = max(self.newest, t_s)
        new = np.zeros(z.shape[0], dtype=bool)
        for i in np.flatnonzero(np.isfinite(z)):
            ts, vs = self.t[i], self.v[i]
            if t_s <= self.newest - self.window_s:
                self.late += 1
                continue
            k = bisect.bisect_right(ts, t_s)
            if float(z[i]) in vs[bisect.bisect_left(ts, t_s) : k]:
                continue  # the same reading again (a stage re-sending its latest set)
            ts.insert(k, t_s)
            vs.insert(k, float(z[i]))
            self.readings += 1
            new[i] = True
        return new

    def take(self, t_s: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per link, the times and values to use at ``t_s`` (module docstring); readings too old are forgotten."""
        times, values = [], []
        self.newest = max(self.newest, t_s)  # a reading older than the window at this output arrives too late
        for i, (ts, vs) in enumerate(zip(self.t, self.v, strict=True)):
            old = bisect.bisect_right(ts, t_s - self.window_s)
            if old:
                del ts[:old], vs[:old]
            upto = bisect.bisect_right(ts, t_s)
            fresh = bisect.bisect_right(ts, self.used_until[i], 0, upto)
            if fresh < upto:
                sel = slice(fresh, upto)
            elif upto:
                sel = slice(upto - 1, upto)
                self.reused += 1
            else:
                times.append(np.zeros(0))
                values.append(np.zeros(0))
                continue
            times.append(np.asarray(ts[sel], dtype=float))
            values.append(np.asarray(vs[sel], dtype=float))
            self.used_until[i] = max(self.used_until[i], ts[sel.stop - 1])
        return times, values

    def stats(self) -> dict[str, Any]:
        return {"window_s": self.window_s, "readings": self.readings, "late_dropped": self.late,
                "reused_link_steps": self.reused}  # fmt: skip


def shift(model: MeasurementModel, pos: np.ndarray, vel: np.ndarray, ages_s: np.ndarray, known: Known) -> np.ndarray:
    """``h(pos) - h(pos - vel * age)`` for each age (A,) -> (A, p): what each reading taken ``age`` seconds ago must
    gain to be the reading at the time of ``pos`` under constant velocity (module docstring)."""
    now = np.asarray(model.h(pos, known), dtype=float)
    out = np.zeros((ages_s.size, now.size))
    for k, age in enumerate(ages_s):
        if age != 0.0:
            out[k] = now - np.asarray(model.h(pos - vel * age, known), dtype=float)
    return out


def align(
    model: MeasurementModel,
    t_s: float,
    times: Sequence[np.ndarray],
    values: Sequence[np.ndarray],
    reference: tuple[np.ndarray, np.ndarray] | None,
    known: Known,
) -> np.ndarray:
    """One reading per link at ``t_s``: each link's readings brought to ``t_s`` and averaged (NaN: none).

    ``reference``: the position at ``t_s`` and the velocity the readings are moved with; None: not moved."""
    out = np.full(len(times), np.nan)
    if reference is None:
        for i, v in enumerate(values):
            if v.size:
                out[i] = float(np.mean(v))
        return out
    pos, vel = reference
    ages = np.unique(np.concatenate([t_s - t for t in times])) if any(t.size for t in times) else np.zeros(0)
    table = shift(model, pos, vel, ages, known)
    for i, (t, v) in enumerate(zip(times, values, strict=True)):
        if v.size:
            rows = np.searchsorted(ages, t_s - t)
            out[i] = float(np.mean(v + table[rows, i]))
    return out


class _Async:
    """What both wrappers share: the window, the track the readings are moved with, the estimator's shape."""

    def __init__(self, inner: Estimator, window_s: float) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"{ASYNC_PARAM}={window_s} must be a positive number of seconds")
        self.inner = inner
        self.model: MeasurementModel = inner.model
        self.name = inner.name
        self.window = _Window(inner.model.p, float(window_s))
        # The track the readings are moved with (module docstring): an EKF on the trusted links' raw readings.
        self.track = ExtendedKalman(inner.model, q_mps2=max(float(inner.q_mps2), 0.05))
        self.trusted = np.zeros(inner.model.p, dtype=bool)  # the links the last valid output rested on
        self.valid_t = -math.inf  # the last time the track was corrected
        self.last_aligned: np.ndarray = np.full(inner.model.p, np.nan)  # the readings at the last output's time

    def __getattr__(self, name: str) -> Any:
        """Anything else is the wrapped estimator's (its parameters, its filters' state): the wrapper adds only the
        time handling."""
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def secure(self) -> bool:
        return self.inner.secure

    @property
    def detects(self) -> bool | None:
        return self.inner.detects

    @property
    def q_mps2(self) -> float:
        return self.inner.q_mps2

    def stats(self) -> dict[str, Any]:
        return {"processing": self.processing, **self.window.stats()}

    def _reference(self, t_s: float, velocity: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
        track = self.track
        if track.t_s is None or not track.started or t_s - self.valid_t > max(
            STALE_WINDOWS * self.window.window_s, STALE_MIN_S
        ):
            # No correction for a while (a gap, an attack beyond tolerance): a velocity extrapolated that far
            # would move the readings by what the estimator no longer knows, and keep it from coming back.
            return None
        f, _ = self.track._cv(max(0.0, t_s - track.t_s))
        x = f @ track.bank.x[0]
        d = self.model.d
        vel = None if velocity is None else self.model.state_velocity(velocity)
        return x[:d], (x[d:] if vel is None else vel)

    def _track_read(self, t_s: float, z: np.ndarray, known: Known) -> None:
        """One time's raw readings into the track, those of the trusted links only, in time order."""
        track = self.track
        use = np.isfinite(z) & self.trusted
        if not track.started or not use.any() or (track.t_s is not None and t_s < track.t_s):
            return  # (a reading older than the track's time is left out of it: the track only moves forward)
        out = track.step(t_s, np.where(use, z, np.nan), known)
        if out.reinitialised or not out.ok:
            self.valid_t = -math.inf  # the track lost itself: no alignment until the next valid output seeds it
        else:
            self.valid_t = t_s

    def _learn(self, est: Estimate) -> None:
        """A valid output says which links to trust, and seeds the track when it has none (or lost itself)."""
        if not (est.ok and est.valid):
            return
        self.trusted = np.zeros(self.model.p, dtype=bool)
        self.trusted[list(est.used)] = True
        if self.track.started and est.t_s - self.valid_t <= max(STALE_WINDOWS * self.window.window_s, STALE_MIN_S):
            return
        d = self.model.d
        cov = np.diag(self.model.sigma_m[:1].repeat(d) ** 2) if est.covariance is None else est.covariance[:d, :d]
        P0 = self.track._initial_cov()
        P0[:d, :d] = cov + 1e-6 * np.eye(d)
        vel = np.zeros(d) if est.velocity_mps is None else np.asarray(est.velocity_mps, dtype=float)
        self.track.reset(np.concatenate([est.position_m, vel]), est.t_s, P0)
        self.valid_t = est.t_s

    def _take(self, t_s: float, z: np.ndarray | None, times: np.ndarray | None, known: Known) -> None:
        if z is None:
            return
        zv = np.asarray(z, dtype=float).reshape(-1)
        if times is None:
            self.read(t_s, zv, known)
            return
        stamps = np.asarray(times, dtype=float).reshape(-1)
        for ts in np.unique(stamps[np.isfinite(zv) & np.isfinite(stamps)]):
            self.read(float(ts), np.where(stamps == ts, zv, np.nan), known)

    def read(self, t_s: float, z: np.ndarray, known: Known = None) -> None:
        raise NotImplementedError

    def _output_readings(self, t_s: float, z: np.ndarray | None, known: Known, velocity: np.ndarray | None,
                         times: np.ndarray | None) -> tuple[np.ndarray, float]:  # fmt: skip
        """The readings an output at ``t_s`` takes (``z`` added to the window first, then all brought to
        ``t_s``), and the seconds that took, which count into the output's step time."""
        t0 = time.perf_counter()
        self._take(t_s, z, times, known)
        za = self._aligned(t_s, known, velocity)
        return za, time.perf_counter() - t0

    def _aligned(self, t_s: float, known: Known, velocity: np.ndarray | None) -> np.ndarray:
        kn = self.model.default_known if known is None else known
        times, values = self.window.take(t_s)
        self.last_aligned = align(self.model, t_s, times, values, self._reference(t_s, velocity), kn)
        return self.last_aligned


class Aligned(_Async):
    """Window alignment (module docstring) around any estimator."""

    processing = "aligned"

    def read(self, t_s: float, z: np.ndarray, known: Known = None) -> None:
        zv = np.asarray(z, dtype=float).reshape(-1)
        new = self.window.add(float(t_s), zv)
        self._track_read(float(t_s), np.where(new, zv, np.nan), self.model.default_known if known is None else known)

    def step(
        self,
        t_s: float,
        z: np.ndarray | None = None,
        known: Known = None,
        velocity: np.ndarray | None = None,
        times: np.ndarray | None = None,
    ) -> Estimate:
        za, spent = self._output_readings(float(t_s), z, known, velocity, times)
        est = self.inner.step(float(t_s), za, known, velocity=velocity)
        self._learn(est)
        object.__setattr__(est, "step_time_s", est.step_time_s + spent)
        return est


class Sequential(_Async):
    """Sequential updates (module docstring) around a filter that takes any subset of its readings per step."""

    processing = "sequential"

    def __init__(self, inner: Estimator, window_s: float) -> None:
        super().__init__(inner, window_s)
        self.ok = False  # the filter has an estimate: readings update it as they come
        self.spent_s = 0.0  # time spent on the readings since the last output

    def _reference(self, t_s: float, velocity: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The filter is its own track: its state predicted to ``t_s``."""
        inner = self.inner
        bank = getattr(inner, "bank", None)
        if not self.ok or inner.t_s is None or bank is None:
            return None
        f, _ = inner._cv(max(0.0, t_s - inner.t_s))
        x = f @ bank.x[0]
        d = self.model.d
        vel = None if velocity is None else self.model.state_velocity(velocity)
        return x[:d], (x[d:] if vel is None else vel)

    def _learn(self, est: Estimate) -> None:
        return  # the filter is its own track

    def read(self, t_s: float, z: np.ndarray, known: Known = None) -> None:
        zv = np.asarray(z, dtype=float).reshape(-1)
        new = self.window.add(float(t_s), zv)
        zv = np.where(new, zv, np.nan)  # a reading seen before updates the filter once
        if not self.ok or not new.any():
            return
        at = float(t_s)
        if self.inner.t_s is not None and at < self.inner.t_s:
            # Out of order: brought to the filter's time with the motion model, then applied there.
            kn = self.model.default_known if known is None else known
            ref = self._reference(self.inner.t_s, None)
            if ref is not None:
                zv = zv + shift(self.model, ref[0], ref[1], np.array([self.inner.t_s - at]), kn)[0]
            at = self.inner.t_s
        est = self.inner.step(at, zv, known)
        self.spent_s += est.step_time_s
        if est.reinitialised or not est.ok:
            self.ok = False  # started again: from the next output's aligned readings

    def step(
        self,
        t_s: float,
        z: np.ndarray | None = None,
        known: Known = None,
        velocity: np.ndarray | None = None,
        times: np.ndarray | None = None,
    ) -> Estimate:
        za, spent = self._output_readings(float(t_s), z, known, velocity, times)  # marks the window's readings used
        spent += self.spent_s
        self.spent_s = 0.0
        if self.ok:
            est = self.inner.step(float(t_s), np.full(self.model.p, np.nan), known, velocity=velocity)
        else:
            est = self.inner.step(float(t_s), za, known, velocity=velocity)
        self.ok = est.ok and not est.reinitialised
        self._learn(est)
        object.__setattr__(est, "step_time_s", est.step_time_s + spent)
        return est


AsyncEstimator = Aligned | Sequential


def wrap(inner: Estimator, window_s: float) -> AsyncEstimator:
    """The asynchronous treatment of ``inner``: sequential updates for a filter that says so, else alignment."""
    return Sequential(inner, window_s) if getattr(inner, "sequential", False) else Aligned(inner, window_s)


def processing(name: str) -> str:
    """How estimator ``name`` takes asynchronous readings: ``sequential`` or ``aligned``."""
    return "sequential" if getattr(get_class(name), "sequential", False) else "aligned"


def create(name: str, model: MeasurementModel, **params: Any) -> Estimator | AsyncEstimator:
    """``estimators.create`` that also takes ``async_window_s``: readings one at a time (module docstring)."""
    window = params.pop(ASYNC_PARAM, None)
    inner = create_registered(name, model, **params)
    return inner if window is None else wrap(inner, float(window))


def default_window(out_times: np.ndarray, read_times: Sequence[np.ndarray] = ()) -> float:
    """The default window (module docstring, "The default window"): one output period (the median spacing of
    ``out_times``), or, when a link is read more slowly than that, the ``COVER_QUANTILE`` quantile of the slowest
    link's reading intervals (``read_times``: per link, its reading times). A link read more seldom than
    ``COVER_MAX_S`` is not covered: the window stays one period and :meth:`Coverage.refusal` names the link and
    the window it needs."""
    out = np.asarray(out_times, dtype=float)
    period = float(np.median(np.diff(out))) if out.size > 1 else 1.0
    cover = 0.0
    for ts in read_times:
        t = np.unique(np.asarray(ts, dtype=float))
        if t.size > 2:
            cover = max(cover, float(np.quantile(np.diff(t), COVER_QUANTILE)))
    return max(period, cover) if cover <= COVER_MAX_S else period


# -- too sparse: what a window at a rate would hold, and the one-line refusal ------------------------------------


@dataclass(frozen=True)
class Coverage:
    """What windows of ``window_s`` seconds ending at the output times hold."""

    window_s: float
    rate_hz: float
    per_second: tuple[float, ...]  # per link: readings per second over the recording
    link_share: tuple[float, ...]  # per link: share of the outputs whose window holds one of its readings
    fix_share: float  # share of the outputs whose window holds the readings of min_sensors links
    min_sensors: int
    gaps_s: tuple[float, ...]  # per link: the window that would hold one of its readings at most outputs

    def refusal(self, ids: Sequence[int]) -> str | None:
        """None when the window and rate suffice; else one line naming each short link and the numbers."""
        short = [k for k, (r, s) in enumerate(zip(self.per_second, self.link_share, strict=True))
                 if r > 0 and s < MIN_LINK_SHARE]  # fmt: skip
        if not short and self.fix_share >= MIN_FIX_SHARE:
            return None
        need = max([self.gaps_s[k] for k in short], default=0.0)
        links = ", ".join(f"{ids[k]}: {self.per_second[k]:.2f}/s in {self.link_share[k]:.0%}" for k in
                          (short or range(len(ids))))  # fmt: skip
        what = (f"{len(short)} link(s) read too seldom" if short else
                f"only {self.fix_share:.0%} of the outputs hold the {self.min_sensors} readings a fix needs "
                f"(needs {MIN_FIX_SHARE:.0%})")  # fmt: skip
        hint = f"give a window of {need:.2g} s or more" if need > 0 else "give a longer window or a lower rate"
        return (f"asynchronous window {self.window_s:g} s at {self.rate_hz:.3g} Hz: {what}; readings per second "
                f"and share of windows holding one, sensor id: {links} (each link needs {MIN_LINK_SHARE:.0%}); "
                f"{hint}")  # fmt: skip


def coverage(
    read_times: Sequence[np.ndarray], out_times: np.ndarray, window_s: float, min_sensors: int
) -> Coverage:
    """How well windows of ``window_s`` at ``out_times`` are filled by each link's reading times (``read_times``)."""
    out = np.asarray(out_times, dtype=float)
    span = float(out[-1] - out[0]) if out.size > 1 else 0.0
    rate = (out.size - 1) / span if span > 0 else 0.0
    held = np.zeros((out.size, len(read_times)), dtype=bool)
    per_second, gaps = [], []
    for i, ts in enumerate(read_times):
        t = np.sort(np.asarray(ts, dtype=float))
        if t.size and out.size:
            k = np.searchsorted(t, out, side="right") - 1  # the newest reading at or before each output
            ok = k >= 0
            held[ok, i] = out[ok] - t[k[ok]] < window_s
        per_second.append(t.size / span if span > 0 else 0.0)
        # the window that holds one of its readings at most outputs: the median spacing, and the 75th percentile
        gaps.append(float(np.quantile(np.diff(t), 0.75)) if t.size > 2 else math.inf)
    share = held.mean(axis=0) if out.size else np.zeros(len(read_times))
    fix = float(np.mean(held.sum(axis=1) >= min_sensors)) if out.size else 0.0
    return Coverage(float(window_s), rate, tuple(per_second), tuple(float(s) for s in share), fix, min_sensors,
                    tuple(gaps))  # fmt: skip

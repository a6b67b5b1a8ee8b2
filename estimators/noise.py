"""Noise as it is: per-link offsets and a noise scale calibrated from an attack-free window.

Real two-way UWB ranges read long by a constant per link (+0.08 to +0.32 m in the LIAS-CUHKSZ
planar recordings, docs/datasets.md), scatter about it by a sigma nobody told the filter, with
heavier tails than a Gaussian's. Every chi-square test in this package assumes zero-mean Gaussian
readings of the stated ``sigma_m``; with offsets of 3-4 sigma it names honest links as liars on
a large share of steps. Calibrating the offsets out (antenna-delay calibration, the standard
practice for two-way ranging) and learning the scale is the fix the measurements support.

:class:`Calibrated` wraps any registered estimator. For the first ``window_s`` seconds (the
calibration window, which must be attack-free: on the ground before take-off, or a stretch the
operator vouches for) it passes the readings to the estimator as it is and keeps them. At the end
of the window it fits :func:`calibrate`: per step a weighted least-squares position from all
readings, per link the residual ``r_i = z_i - h_i(fix)``; the offset ``b_i`` is the median of
``r_i`` (refitted three times with the offsets removed, so one long link does not bend the
others' fixes); the scale is robust, ``s_i = 1.4826 MAD(r_i - b_i) sqrt(p / (p - d))`` (the fix
absorbs d of the p degrees of freedom), floored at the links' median (a short window of correlated
errors can make one link's scale come out low by chance), times one tail factor ``k >= 1`` shared
by all links (:func:`tail_factor`: a Student-t fitted to the pooled residuals' 99 % point, read at
the per-reading level of the naming tests), so those tests fire at about their stated level on
heavy-tailed noise instead of at several times it. The window tests' variance is multiplied by
:func:`window_vif` from the residuals' autocorrelation. From then on the estimator is rebuilt
on the model with ``sigma_m = s``, warmed up on the last ``WARM_STEPS`` corrected readings of
the window, and reads ``z - b``.

It says what it did: the window must hold ``MIN_STEPS`` steps with a fix and, per link, ``MIN_LINK_READINGS``
readings in them (:func:`count_window`); if not, it refuses (:meth:`WindowCount.refusal`, one line naming every
link's count and what it needs) and the estimator goes on uncalibrated with :meth:`Calibrated.report` saying so.
After the window (``calibration_track``, default on, secure estimators only) the offsets keep following the
room within a drift bound a slow ramp cannot hide under (:mod:`estimators.offsets`), the naming tests judge only
what no offset within that bound of the window's explains (``OffsetTracker.beyond``, ``Namer.band``), and a jump
names a link only when ``CONFIRM_STEPS`` readings in a row fail it (:class:`estimators.attribution.Namer`): on the
LIAS recordings these took the honest links named from 49-59 % of the clean steps of the mid run to 0-0.1 % on
the tags the settings were chosen on and 0 % on the held-out tag, at a price: a one-link bias is named on every
step only from 0.8 m, not 0.5 m (estimators/README.md, "Real noise").

What it cannot do: an offset pattern that a shift of the position explains (its projection on
the span of the range Jacobian at the window's positions) stays in the position, as it would with
any self-calibration without truth; an attacker present during the window is calibrated in (the
offsets absorb a constant bias, the scale a noise inflation). The time correlation of real
errors (about 2 s) is not whitened: the evidence window still sees correlated honest errors.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.stats import norm
from scipy.stats import t as student_t

from estimators.aligned import ASYNC_PARAM, AsyncEstimator
from estimators.aligned import create as create_estimator
from estimators.base import EVIDENCE_STEPS, Estimate, Estimator
from estimators.drift import InnovationWindow
from estimators.models import Known, MeasurementModel
from estimators.motion import ProcessNoiseFit, fit_process_noise
from estimators.offsets import OffsetTracker

WARM_STEPS = 20  # readings replayed into the rebuilt estimator (2 s at 10 Hz) so it takes over converged
MIN_STEPS = 20  # steps of the window with a fix (min_sensors readings) the fit needs
# Readings of each link, in steps with a fix, the fit needs: its offset is their median and its scale their MAD; with
# 20 the median's own spread is about 0.28 sigma (1.25 sigma / sqrt(20)), a third of the naming tests' margin.
MIN_LINK_READINGS = 20
CALIBRATION_PARAM = "calibration_s"
CONFIRM_STEPS = 2  # real ranges: a jump names a link when two readings in a row fail (attribution.Namer)
TRACK_PARAM = "calibration_track"  # follow the offsets online within their drift bound (default true)
TAIL_PARAM = "calibration_tail_dof"  # optional: Student-t dof of the errors, measured beforehand


@dataclass(frozen=True)
class Calibration:
    offsets_m: np.ndarray  # (p,) subtracted from every reading after the window
    sigma_m: np.ndarray  # (p,) the sigma the rebuilt estimator is told
    tail_factor: float  # k: the Gaussian-matching inflation of the robust scale
    steps: int  # steps of the window that gave a fix
    window_vif: float = 1.0  # variance inflation of a WINDOW-step mean from the residuals' autocorrelation
    reading_counts: np.ndarray | None = None  # (p,) how many readings of each link the fit used (steps with a fix)


@dataclass(frozen=True)
class WindowCount:
    """What a calibration window holds: its steps, those with a fix, and each link's readings in them."""

    window_s: float
    span_s: float  # the time the window's steps cover (less than window_s: the readings ended first)
    steps: int
    fixes: int  # steps with at least min_sensors readings (a least-squares fix exists)
    reading_counts: tuple[int, ...]  # per link: how many readings in steps with a fix (what the fit can use)

    def refusal(self, ids: Sequence[int]) -> str | None:
        """None if the window can be calibrated on; else one line naming each link's count and what it needs."""
        per_link = ", ".join(f"{sid}: {n}" for sid, n in zip(ids, self.reading_counts, strict=True))
        short = [str(sid) for sid, n in zip(ids, self.reading_counts, strict=True) if n < MIN_LINK_READINGS]
        if self.span_s < self.window_s:
            return (f"calibration window {self.window_s:g} s: the readings end after {self.span_s:.1f} s "
                    f"({self.steps} steps); give a shorter window or a longer recording")  # fmt: skip
        if not short and self.fixes >= MIN_STEPS:
            return None
        return (f"calibration window {self.window_s:g} s holds too few readings to calibrate: {self.fixes} of "
                f"{self.steps} steps have a fix (needs {MIN_STEPS}); readings per link in them, sensor id: count, "
                f"{per_link} (each link needs {MIN_LINK_READINGS}"
                + (f"; short: {', '.join(short)}" if short else "")
                + "); give a longer window")  # fmt: skip


def window_length(t_s: np.ndarray, window_s: float) -> int:
    """How many steps :class:`Calibrated` collects from times ``t_s``: up to and including the first step at
    least ``window_s`` after the first (all of them if the times end before)."""
    t = np.asarray(t_s, dtype=float)
    if t.size == 0:
        return 0
    late = np.flatnonzero(t - t[0] >= window_s)
    return int(late[0]) + 1 if late.size else int(t.size)


def count_window(model: MeasurementModel, t_s: np.ndarray, z: np.ndarray, window_s: float) -> WindowCount:
    """Count the readings a calibration window of ``window_s`` seconds would hold (``z`` (T, p), NaN missing)."""
    n = window_length(t_s, window_s)
    win = np.isfinite(np.asarray(z, dtype=float)[:n])
    fix = win.sum(axis=1) >= model.min_sensors
    span = float(t_s[n - 1] - t_s[0]) if n else 0.0
    counts = tuple(int(v) for v in win[fix].sum(axis=0))
    return WindowCount(float(window_s), span, n, int(fix.sum()), counts)


def _fix(model: MeasurementModel, z: np.ndarray, known: Known, start: np.ndarray, n_iter: int = 8) -> np.ndarray | None:
    """Weighted least squares on the finite readings (Gauss-Newton from ``start``); None if too few."""
    use = np.isfinite(z)
    if use.sum() < model.min_sensors:
        return None
    w = 1.0 / model.sigma_m[use] ** 2
    pos = start.astype(float).copy()
    for _ in range(n_iter):
        hx, jac = model.h_jac(pos, known)
        r = z[use] - hx[use]
        j = jac[use]
        step = np.linalg.lstsq(j * np.sqrt(w)[:, None], r * np.sqrt(w), rcond=None)[0]
        pos = model.clip(pos + step)
        if float(step @ step) < 1e-10:
            break
    return pos


def calibrate(
    model: MeasurementModel,
    z: np.ndarray,
    known: list[Known],
    test_level: float = 1e-3,
    passes: int = 3,
    tail_dof: float | None = None,
) -> Calibration | None:
    """Offsets and scale from a window of readings ``z`` (T, p) with their ``known`` inputs; see the module doc."""
    p, d = model.p, model.d
    offsets = np.zeros(p)
    resid = np.full(z.shape, np.nan)
    for _ in range(passes):
        start = model.initial_pos()
        resid[:] = np.nan
        for k in range(z.shape[0]):
            zk = z[k] - offsets
            guess = model.initial_guess(np.where(np.isfinite(zk), zk, np.nan), known[k])
            pos = _fix(model, zk, known[k], guess if np.isfinite(guess).all() else start)
            if pos is None:
                continue
            resid[k] = zk - model.h(pos, known[k])
            start = pos
        steps = int(np.isfinite(resid).any(axis=1).sum())
        used = np.isfinite(resid).sum(axis=0)
        if steps < MIN_STEPS or used.min() < MIN_LINK_READINGS:
            return None  # the caller's WindowCount says why (count_window counts the same readings)
        offsets = offsets + np.nan_to_num(np.nanmedian(resid, axis=0))
    centred = resid - np.nanmedian(resid, axis=0)
    dof = np.sqrt(p / max(p - d, 1))
    robust = 1.4826 * np.nanmedian(np.abs(centred), axis=0) * dof
    robust = np.where(np.isfinite(robust) & (robust > 1e-4), robust, model.sigma_m)
    # A short window of time-correlated errors holds few independent samples, so one link's scale can come out
    # low by chance (0.045 m against a true 0.069 in 20 s at a 2 s correlation time): no link below the median.
    robust = np.maximum(robust, float(np.median(robust)))
    standard = np.abs(centred / robust)
    if tail_dof is None:
        factor = tail_factor(standard[np.isfinite(standard)], test_level)
    else:  # the tails measured on this hardware beforehand (docs/datasets.md), not guessed from the window
        factor = max(1.0, float(_t_ratio(np.array([float(tail_dof)]), 1.0 - test_level)[0]))
    vif = window_vif(centred, EVIDENCE_STEPS)
    return Calibration(offsets_m=offsets, sigma_m=robust * factor, tail_factor=factor, steps=steps, window_vif=vif,
                       reading_counts=used)  # fmt: skip


_DOFS = np.geomspace(2.2, 300.0, 120)


def _t_ratio(dof: np.ndarray, two_sided: float) -> np.ndarray:
    """Student-t's two-sided quantile over a Gaussian's, both in units of their own MAD-based scale."""
    mad_t = student_t.ppf(0.75, dof)
    return (student_t.ppf(0.5 + two_sided / 2.0, dof) / mad_t) / (norm.ppf(0.5 + two_sided / 2.0) / norm.ppf(0.75))


def tail_factor(standard: np.ndarray, test_level: float, fit_quantile: float = 0.99) -> float:
    """How much to widen a robust (MAD) scale so a per-reading test at ``test_level`` fires at that level.

    A window of a few hundred readings cannot see the 1e-3 tail the tests use, so the tail is read at
    ``fit_quantile`` (99 %: well populated) and extrapolated with the Student-t whose 99 % point over its
    MAD matches the data's: its degrees of freedom are fitted, then its ``1 - test_level`` point is
    compared with the Gaussian's. 1 for Gaussian data (or lighter tails).
    """
    if standard.size < 100:
        return 1.0
    ratio = float(np.quantile(standard, fit_quantile) / norm.ppf(0.5 + fit_quantile / 2.0))
    at_fit = _t_ratio(_DOFS, fit_quantile)  # decreasing in dof towards 1
    if ratio <= 1.0 or ratio <= float(at_fit[-1]):
        return 1.0
    dof = float(np.interp(-ratio, -at_fit, _DOFS))  # at_fit falls as dof grows: interpolate on its negative
    return max(1.0, float(_t_ratio(np.array([dof]), 1.0 - test_level)[0]))


def window_vif(resid: np.ndarray, window: int) -> float:
    """``1 + 2 sum_k (1 - k/T) rho(k)`` (k = 1..T-1): the variance of a T-step mean over that of white errors.

    ``rho`` is the lag autocorrelation of the residuals (T, p), pooled over links; negative sums count as 1.
    """
    x = np.where(np.isfinite(resid), resid, 0.0)
    ok = np.isfinite(resid)
    x = x - np.where(ok, np.nanmean(resid, axis=0), 0.0)
    energy = float(np.sum(x * x))
    if energy <= 0 or x.shape[0] <= window:
        return 1.0
    total = 0.0
    for k in range(1, window):
        both = ok[:-k] & ok[k:]
        rho = float(np.sum(x[:-k] * x[k:] * both)) / energy * x.shape[0] / max(x.shape[0] - k, 1)
        total += (1.0 - k / window) * rho
    return max(1.0, 1.0 + 2.0 * total)


class Calibrated:
    """An estimator behind a calibration window (see the module docstring); the same ``step`` shape."""

    def __init__(
        self,
        name: str,
        model: MeasurementModel,
        window_s: float,
        tail_dof: float | None = None,
        track: bool = True,
        **params: Any,
    ) -> None:
        if not window_s > 0:
            raise ValueError(f"{CALIBRATION_PARAM}={window_s} must be positive (seconds)")
        if tail_dof is not None and not tail_dof > 2:
            raise ValueError(f"{TAIL_PARAM}={tail_dof} must exceed 2 (a finite variance)")
        self.tail_dof = tail_dof
        self.name = name
        self.model = model
        self.window_s = float(window_s)
        self.params = params
        self.inner: Estimator | AsyncEstimator = create_estimator(name, model, **params)
        self.process_noise: ProcessNoiseFit | None = None  # q fitted on the window (estimators.motion)
        self.track = bool(track)
        self.tracker: OffsetTracker | None = None  # estimators.offsets, from the end of the window on
        self.calibration: Calibration | None = None
        self._t0: float | None = None
        self._z: list[np.ndarray] = []
        self._known: list[Known] = []
        self._t: list[float] = []
        self._velocity: list[np.ndarray | None] = []
        self._done = False
        self.refused: str | None = None  # why the window could not be calibrated on (WindowCount.refusal)
        self.count: WindowCount | None = None

    @property
    def secure(self) -> bool:
        return self.inner.secure

    @property
    def detects(self) -> bool | None:
        return self.inner.detects

    @property
    def core(self) -> Estimator:
        """The estimator itself (inside an asynchronous wrapper, if any)."""
        return self.inner.inner if isinstance(self.inner, AsyncEstimator) else self.inner

    def read(self, t_s: float, z: np.ndarray, known: Known = None) -> None:
        """Readings taken at ``t_s``, one at a time (asynchronous processing, estimators.aligned): corrected once
        calibrated; the window fits on the readings each output brought to its time."""
        if not isinstance(self.inner, AsyncEstimator):
            raise TypeError(f"{self.name} was built without {ASYNC_PARAM}: it takes readings only with step()")
        zv = np.asarray(z, dtype=float).reshape(-1)
        self.inner.read(t_s, zv if self.calibration is None else zv - self._offsets(), known)

    def step(self, t_s: float, z: np.ndarray | None = None, known: Known = None, velocity: np.ndarray | None = None,
             times: np.ndarray | None = None) -> Estimate:  # fmt: skip
        zv = None if z is None else np.asarray(z, dtype=float).reshape(-1)
        if isinstance(self.inner, AsyncEstimator):
            if zv is not None and self.calibration is not None:
                zv = zv - self._offsets()
            out = self.inner.step(t_s, zv, known, velocity=velocity, times=times)
            if self._done:
                if self.tracker is not None:
                    self._track(t_s, out)
                return out
            zv = self.inner.last_aligned  # what the window fits on: the readings at the output's time
        else:
            assert zv is not None, "a synchronous estimator takes its readings with each step"
            if self._done:
                if self.calibration is None:
                    return self.inner.step(t_s, zv, known, velocity=velocity)
                out = self.inner.step(t_s, zv - self._offsets(), known, velocity=velocity)
                if self.tracker is not None:
                    self._track(t_s, out)
                return out
            out = self.inner.step(t_s, zv, known, velocity=velocity)
        if self._t0 is None:
            self._t0 = float(t_s)
        # Calibrating: the estimate is the estimator's, but nothing is tested yet (no alarm, nobody named) and
        # it is not claimed valid.
        out = replace(out, attacked=frozenset(), alarm=False, valid=False,
                      own_attacked=None if out.own_attacked is None else frozenset(),
                      own_alarm=None if out.own_alarm is None else False)  # fmt: skip
        self._z.append(zv)
        self._known.append(self.model.default_known if known is None else known)
        self._t.append(float(t_s))
        self._velocity.append(velocity)
        if float(t_s) - self._t0 >= self.window_s:
            self._finish()
        return out

    def _finish(self) -> None:
        self._done = True
        z = np.array(self._z)
        alpha = float(self.params.get("alpha", 0.01))
        level = 1.0 - (1.0 - alpha / 2.0) ** (1.0 / self.model.p)  # the per-reading Sidak level of attribution
        self.count = count_window(self.model, np.array(self._t), z, self.window_s)
        self.refused = self.count.refusal(self.model.ids())
        if self.refused is None:
            self.calibration = calibrate(self.model, z, self._known, test_level=level, tail_dof=self.tail_dof)
            if self.calibration is None:  # cannot happen while count_window counts what calibrate uses; never silent
                self.refused = f"calibration window {self.window_s:g} s: the fit found too few readings"
        if self.calibration is not None:
            tuned = replace(self.model, sigma_m=self.calibration.sigma_m)
            params = dict(self.params)
            if self.process_source() == "fitted":
                # No motion input and no q given: the constant-velocity model's process noise from the window.
                zc = z - self.calibration.offsets_m
                self.process_noise = fit_process_noise(tuned, np.array(self._t), zc, self._known)
                if self.process_noise is not None:
                    params["q_mps2"] = self.process_noise.q_mps2
            self.inner = create_estimator(self.name, tuned, **params)
            self.core.namer.window_vif = self.calibration.window_vif
            if self.track and self.core.secure:
                self.core.namer.confirm_steps = CONFIRM_STEPS
                self.tracker = OffsetTracker(self.model.p)
                self.core.namer.band = self.tracker.beyond
            drift = getattr(self.core, "drift", None)
            if isinstance(drift, InnovationWindow):
                drift.vif = self.calibration.window_vif
            for k in range(max(0, len(self._t) - WARM_STEPS), len(self._t)):
                self.inner.step(self._t[k], z[k] - self.calibration.offsets_m, self._known[k],
                                velocity=self._velocity[k])  # fmt: skip
        self._z, self._known, self._velocity = [], [], []

    def _offsets(self) -> np.ndarray:
        """What is subtracted from each link's readings: the window's offsets, plus how far they have followed the
        room since (estimators.offsets)."""
        assert self.calibration is not None
        if self.tracker is None:
            return self.calibration.offsets_m
        return self.calibration.offsets_m + self.tracker.delta

    def _track(self, t_s: float, out: Estimate) -> None:
        """Let the offsets follow the room (estimators.offsets) from a step claimed valid, on links named neither
        now nor in the evidence window."""
        assert self.tracker is not None
        core = self.core
        if not (out.ok and out.valid and not out.alarm):
            self.tracker.update(t_s, None, np.zeros(self.model.p, dtype=bool))
            return
        trusted = ~core.accused.any(axis=0)
        self.tracker.update(t_s, core.namer.last_resid, trusted)

    def report(self) -> dict[str, Any]:
        """What the window did, for results.json: ``status`` calibrated, refused (``reason``: the one line of
        :meth:`WindowCount.refusal`) or incomplete (the readings ended inside the window); per link (wire sensor
        id) the readings the fit used, the offset subtracted and the sigma the estimator is told."""
        ids = self.model.ids()
        out: dict[str, Any] = {"window_s": self.window_s, "tail_dof": self.tail_dof}
        if not self._done:
            n = len(self._t)
            span = self._t[-1] - self._t[0] if n else 0.0
            reason = f"calibration window {self.window_s:g} s: the readings ended after {span:.1f} s ({n} steps)"
            return {**out, "status": "incomplete", "reason": reason, "steps": n}
        count = self.count
        assert count is not None
        out.update(steps=count.steps, steps_with_fix=count.fixes)
        cal = self.calibration
        if cal is None:
            links = {str(sid): {"readings": n} for sid, n in zip(ids, count.reading_counts, strict=True)}
            return {**out, "status": "refused", "reason": self.refused, "links": links}
        used = cal.reading_counts if cal.reading_counts is not None else np.array(count.reading_counts)
        links = {
            str(sid): {"readings": int(n), "offset_m": round(float(b), 4), "sigma_m": round(float(sg), 4),
                       "stated_sigma_m": round(float(s0), 4)}
            for sid, n, b, sg, s0 in zip(ids, used, cal.offsets_m, cal.sigma_m, self.model.sigma_m, strict=True)
        }  # fmt: skip
        tracker = self.tracker
        if tracker is not None:  # how far each link's offset has followed the room since the window
            for sid, drift, most in zip(ids, tracker.delta, tracker.most, strict=True):
                links[str(sid)].update(drift_m=round(float(drift), 4), drift_max_m=round(float(most), 4))
            out["tracking"] = {"tau_s": tracker.tau_s, "rate_mps": tracker.rate_mps, "bound_m": tracker.bound_m,
                               "band_m": tracker.band_m, "confirm_steps": CONFIRM_STEPS}  # fmt: skip
        else:
            out["tracking"] = None
        return {**out, "status": "calibrated", "tail_factor": round(cal.tail_factor, 4),
                "window_vif": round(cal.window_vif, 4), "links": links,
                "process_noise": self.process_report()}  # fmt: skip

    def process_source(self) -> str:
        """Where the process noise comes from: ``motion input`` (the vehicle's velocity drives the prior),
        ``given`` (``q_mps2`` set), else ``fitted`` on the window (estimators.motion)."""
        if self.params.get("velocity_std_mps") is not None:
            return "motion input"
        return "given" if "q_mps2" in self.params else "fitted"

    def process_report(self) -> dict[str, Any]:
        """``q_mps2`` the estimator runs with and where it comes from (results.json ``calibration.process_noise``)."""
        source = self.process_source()
        if self.process_noise is not None:
            return self.process_noise.report()
        q = round(float(self.core.q_mps2), 4)
        if source == "fitted":  # the window held too few fixes for the fit: said, not hidden
            return {"q_mps2": q, "source": "default (too few fixes to fit)"}
        return {"q_mps2": q, "source": source}


def create(name: str, model: MeasurementModel, **params: Any) -> Estimator | Calibrated:
    """``estimators.create`` that also takes ``calibration_s`` (seconds of attack-free window; see above) and
    ``calibration_tail_dof`` (the errors' Student-t degrees of freedom measured beforehand, e.g. 6.2 for the
    LIAS-CUHKSZ hardware, docs/datasets.md; without it the tail factor is fitted on the window) and
    ``calibration_track`` (default true: a secure estimator's offsets follow the room online within the drift
    bound of estimators.offsets, and a jump names a link after ``CONFIRM_STEPS`` readings in a row; false keeps
    the window's offsets fixed and names on one reading)."""
    window = params.pop(CALIBRATION_PARAM, None)
    tail = params.pop(TAIL_PARAM, None)
    track = params.pop(TRACK_PARAM, None)
    if track is not None and not isinstance(track, bool):
        raise ValueError(f"{TRACK_PARAM}={track!r} must be true or false")
    if window is None:
        for key, value in ((TAIL_PARAM, tail), (TRACK_PARAM, track)):
            if value is not None:
                raise ValueError(f"{key} needs {CALIBRATION_PARAM}")
        return create_estimator(name, model, **params)
    return Calibrated(name, model, float(window), tail_dof=None if tail is None else float(tail),
                      track=True if track is None else track, **params)  # fmt: skip

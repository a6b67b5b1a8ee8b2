"""The one shape every estimator has: ``reset(...)``, ``step(t_s, z) -> Estimate``.

Subclasses implement ``_reset`` and ``_step``; this base class owns the
parameters every estimator shares (how many sensors may be attacked ``s``, the
false-alarm level ``alpha`` that sets all chi-square thresholds, the process
noise ``q_mps2`` of the constant-velocity model and the initial spreads), the
clock, NaN handling of the input and the timing of each step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from estimators.attribution import Namer, Trail, agreeing, explain, sidak_gate
from estimators.bank import Chi2Table, EkfBank, cv_matrices, gauss_newton, inv_small
from estimators.envelope import MAX_SPEED_MPS, SLACK_M, Envelope
from estimators.models import Known, MeasurementModel

# Where the built-ins' defaults were chosen (``Estimator.tuned_on``): during development, by hand, on the bundled
# scenarios the suite's studies also fly, before the suite had a tuning split. Their suite figures are therefore
# not held out, and a reader should weigh them so (docs/bench.md, "Tuning").
TUNED_ON_BUNDLED = "by hand on the bundled scenarios (the suite's own; not held out)"
EVIDENCE_STEPS = 10  # the evidence window: the last second at 10 Hz
EVIDENCE_MIN = 3  # a reading counts as accused when named on at least this many of its steps


@dataclass(frozen=True, eq=False)
class Estimate:
    """One step's output.

    ``position_m`` has the model's d entries (2-D anchors: north, east; scalar
    group: the distance; two vehicles: n1, e1, n2, e2). ``velocity_mps`` is
    None for snapshot estimators. ``covariance`` is over ``[position, velocity]``
    when velocity is modelled, else over position. ``attacked`` and ``used`` are
    indices into z; ``attacked`` is decided by :mod:`estimators.attribution` (family-wise level alpha per
    step) for every estimator with the shared attribution on (``attribution``, by default the secure ones),
    else it is the method's own naming. ``alarm``:
    the readings cannot single out an attacked set of at most s sensors (more
    are attacked than tolerated, or the model is wrong). ``ok`` is False while
    no estimate exists yet (position is NaN then). ``valid`` is False when the
    estimate is degraded: beyond what the estimator can correct, not to be
    trusted (an alarm that the readings of this step confirm at a ten times
    smaller false-alarm level: no p - s of them agree on one position near the
    trail of valid estimates); the position is then the fewest-liars
    explanation's where one exists (``attribution.explain``), else the last
    position the trail knew (held, not extrapolated). ``valid`` is also False (the answer unchanged) while the
    evidence of the last second says more readings lie than are tolerated: in some tolerance group, more than its
    tolerance were each named on at least ``EVIDENCE_MIN`` of the last ``EVIDENCE_STEPS`` steps. A few small
    liars can take turns at looking honest (three relayed links at 5 sigma: one step leaves two of them out,
    the next another two), so every step alone finds at most s liars and a consistent answer, which can be
    further off than the plain EKF; the window sees all of them. An alarm that the readings do not confirm
    (a filter surprised by
    a manoeuvre) leaves it valid. ``nis``: for estimators whose output is a Kalman filter's, that filter's
    normalised innovation squared this step and its degrees of freedom, ``(nu^T S^-1 nu, readings used)``;
    a consistent filter averages 1 per degree of freedom. None for snapshot estimators and steps without
    an update. ``ambiguous`` (then ``valid`` is False too): a tie, two explanations with no more liars than the
    one output that put the vehicle in different places: the mirror image of the output across a line or plane
    of anchors (``MeasurementModel.mirrors``; the layout check refuses an ``s`` that allows it inside the flight
    region, so it fires outside it), or fewest-liars explanations that disagree beyond tolerance.
    """

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray | None
    covariance: np.ndarray | None
    attacked: frozenset[int]
    alarm: bool
    step_time_s: float
    used: frozenset[int] = frozenset()
    ok: bool = True
    valid: bool = True
    nis: tuple[float, int] | None = None
    # The method's own claim, before the shared attribution judged its output (``attacked``/``alarm`` as its
    # ``_step`` returned them); None for a method that does not detect (``Estimator.detects`` False).
    own_attacked: frozenset[int] | None = None
    own_alarm: bool | None = None
    ambiguous: bool = False
    # The output left the envelope the anchors' geometry and the motion bound allow, or the filter lost track
    # (estimators.envelope): reported on the envelope, alarm set, not valid, and the estimator started again.
    reinitialised: bool = False


def _indices(mask: np.ndarray) -> frozenset[int]:
    return frozenset(np.flatnonzero(mask).tolist())


def _as_indices(readings: object, p: int) -> frozenset[int]:
    """Indices into z from a boolean mask of length p or from an iterable of indices (each checked)."""
    arr = np.asarray(list(readings) if isinstance(readings, set | frozenset) else readings)
    if arr.dtype == bool:
        if arr.shape != (p,):
            raise ValueError(f"a reading mask must have {p} entries, got shape {arr.shape}")
        return _indices(arr)
    out = frozenset(int(i) for i in arr.reshape(-1).tolist())
    if any(not 0 <= i < p for i in out):
        raise ValueError(f"reading indices {sorted(out)} must lie in 0..{p - 1}")
    return out


def _mahalanobis(gap: np.ndarray, cov: np.ndarray) -> float:
    return float(gap @ np.linalg.solve(cov + 1e-12 * np.eye(gap.shape[0]), gap))


def _mask(indices: frozenset[int], p: int) -> np.ndarray:
    out = np.zeros(p, dtype=bool)
    out[list(indices)] = True
    return out


class Estimator:
    """Common parameters and bookkeeping; see the module docstring."""

    name: ClassVar[str] = ""
    # A secure estimator: one that claims to tolerate up to ``s`` attacked readings. The flag does one thing: the
    # shared attribution (estimators.attribution, ``_attribute``) may run on its output, judging it, naming the
    # attacked readings and, beyond tolerance, replacing the position. ``attribution`` (a constructor keyword)
    # switches that per instance; it defaults to ``secure``. Studies run a secure method twice, its own output
    # and its output with the attribution (two rows: ``name`` and ``name+attribution``, docs/bench.md).
    secure: ClassVar[bool] = False
    # Whether the method itself claims detections (its _step's attacked/alarm are recorded as own_*);
    # None: as ``secure``. A method that is not ``secure`` but names readings itself sets it True.
    detects: ClassVar[bool | None] = None
    # Where the defaults were chosen (shown on the suite's leaderboard beside the method): a plugin says e.g.
    # "suite v1 tuning split, 3 points"; empty: not declared.
    tuned_on: ClassVar[str] = ""
    motion_input: ClassVar[bool] = False  # reads the vehicle's own velocity (``step(..., velocity=)``)
    # Takes readings one at a time as sequential updates (any subset of z per step; estimators.aligned): filters.
    # The others take asynchronous readings through a window brought to a common time (estimators.aligned).
    sequential: ClassVar[bool] = False

    def __init__(
        self,
        model: MeasurementModel,
        *,
        s: int | None = None,
        alpha: float = 0.01,
        q_mps2: float = 0.5,
        p0_pos_m: float = 0.5,
        p0_vel_mps: float = 0.5,
        n_iter: int = 6,
        velocity_std_mps: float | None = None,
        max_speed_mps: float = MAX_SPEED_MPS,
        motion_slack_m: float = SLACK_M,
        attribution: bool | None = None,
    ) -> None:
        self.model = model
        # Whether the shared attribution runs on this instance's output (None: as the class's ``secure``).
        self.attribution = self.secure if attribution is None else bool(attribution)
        # Never unsafe: outputs outside the anchors' box or the motion bound are caught here (estimators.envelope).
        self.envelope = Envelope.of(model, max_speed_mps, motion_slack_m)
        if velocity_std_mps is not None and not (self.motion_input and velocity_std_mps > 0):
            raise ValueError(
                f"velocity_std_mps={velocity_std_mps}: {self.name} has no motion input"
                if not self.motion_input
                else f"velocity_std_mps={velocity_std_mps} must be positive"
            )
        # The motion input: the vehicle's own velocity estimate (LOCAL_POSITION_NED vx, vy, vz), read by the filters
        # as a measurement of their velocity state with this std, so the process model follows how the vehicle
        # says it moves. It must come from sensors the attacked readings do not feed (IMU, flow, GPS).
        self.velocity_std_mps = velocity_std_mps
        self.velocity_in: np.ndarray | None = None
        self.s = model.max_correctable if s is None else int(s)
        if self.s < 0:
            raise ValueError(f"s={self.s} must not be negative")
        if self.s > model.max_correctable:
            # More liars than the layout can correct over its flight region: two explanations with s liars each
            # could put the vehicle in different places, and no estimator can tell which (observability.py).
            raise ValueError(model.support().explain(self.s))
        self.alpha = alpha
        self.chi = Chi2Table(alpha, 4 * model.p)
        # Confirming an alarm from one step's readings alone: ten times stricter, so noise alone seldom degrades.
        self.chi_confirm = Chi2Table(alpha / 10.0, 4 * model.p)
        self.gate1 = float(self.chi(1))  # one reading's test at level alpha (the detectors' own decisions)
        self.q_mps2 = q_mps2
        self.q_axes = model.axis_noise(q_mps2)  # per axis: a model may let one axis move faster (the climb)
        self.p0_pos_m = p0_pos_m
        self.p0_vel_mps = p0_vel_mps
        self.n_iter = n_iter
        self.t_s: float | None = None
        # Lines and planes of anchors on which p - 2s readings could sit: where a tie is possible at all.
        self.mirrors = model.mirrors(model.p - 2 * self.s) if self.attribution and self.s > 0 else []
        self.reset()

    @classmethod
    def applies_to(cls, model: MeasurementModel) -> bool:
        """Whether this estimator can run on ``model`` (most run on any; interval fusion needs one quantity)."""
        return True

    # -- the public shape -------------------------------------------------
    def reset(self, x0: np.ndarray | None = None, t_s: float = 0.0, P0: np.ndarray | None = None) -> None:
        """Forget the past. ``x0``: position (d) or position+velocity (2d); None = bootstrap from data."""
        self.t_s = None if x0 is None else float(t_s)
        # Where a snapshot fix's cold start begins after the envelope restarted the estimator (``_guard``): the
        # last position claimed valid; None (a fresh start): the model's own guess.
        self.restart_pos: np.ndarray | None = None
        self.namer = Namer(self.model, self.alpha)  # naming attacked readings at a family-wise alpha
        self.trail = Trail(self.model.d)  # where the vehicle can be, for judging alarms and explanations
        self.accused = np.zeros((EVIDENCE_STEPS, self.model.p), dtype=bool)  # ring: who was named, last steps
        self.accused_k = 0
        if self.envelope is not None:  # forget the motion bound's anchor point; a given x0 is the new one
            self.envelope.last_pos, self.envelope.last_t = None, None
        x = None
        if x0 is not None:
            x0 = np.asarray(x0, dtype=float).reshape(-1)
            x = np.concatenate([x0, np.zeros(self.model.d)]) if x0.size == self.model.d else x0.copy()
            if self.envelope is not None and np.isfinite(x[: self.model.d]).all():
                self.envelope.accept(x[: self.model.d], float(t_s))
        self._reset(x, self._initial_cov() if P0 is None else np.asarray(P0, dtype=float))

    def step(self, t_s: float, z: np.ndarray, known: Known = None, velocity: np.ndarray | None = None) -> Estimate:
        """Take one reading vector (NaN = missing) at time t_s; ``known`` e.g. the laser height; ``velocity`` the
        vehicle's own NED velocity estimate (m/s; ``model.state_velocity`` maps it onto the state), read only by
        estimators built with ``velocity_std_mps``."""
        t0 = time.perf_counter()
        self.velocity_in = None
        if velocity is not None and self.velocity_std_mps is not None:
            self.velocity_in = self.model.state_velocity(velocity)
        zv = np.asarray(z, dtype=float).reshape(-1)
        if zv.shape[0] != self.model.p:
            raise ValueError(f"{self.name}: expected {self.model.p} readings, got {zv.shape[0]}")
        if not np.isfinite(zv).all():
            zv = np.where(np.isfinite(zv), zv, np.nan)  # +-inf from a garbled frame counts as missing
        dt_s = 0.0 if self.t_s is None else max(0.0, float(t_s) - self.t_s)
        self.t_s = float(t_s)
        kn = self.model.default_known if known is None else known
        est = self._step(float(t_s), dt_s, zv, kn)
        if self.secure if self.detects is None else self.detects:
            object.__setattr__(est, "own_attacked", est.attacked)
            object.__setattr__(est, "own_alarm", est.alarm)
        if est.ok and self.attribution:
            self._attribute(zv, est, kn)
        if est.ok and self.envelope is not None:
            self._guard(est)
        # The Estimate is frozen for its readers; stamping our own fresh instance costs far less than replace().
        object.__setattr__(est, "step_time_s", time.perf_counter() - t0)
        return est

    def _attribute(self, z: np.ndarray, est: Estimate, known: Known) -> None:
        """Judge the output against the trail, name the attacked readings (``attribution``); fills in ``est``.

        ``est`` is this step's fresh instance: its fields are replaced in place so that position, covariance,
        velocity and ``used`` always describe the same answer.
        """
        model, d = self.model, self.model.d
        prior = self.trail.predict_to(est.t_s)
        cov = np.zeros((d, d)) if est.covariance is None else est.covariance[:d, :d]
        pos, used = est.position_m, _mask(est.used, model.p)
        support = used  # the readings a reading is judged against and the trail is fed from
        named = None
        # An estimate that leaves the trail (at level alpha: judging costs a subset search, not a verdict) is
        # judged like an alarm: beyond tolerance an estimator's own tests can accept a coincidental consistent
        # subset far from where the vehicle is, and the step it jumps there must not drag the trail along.
        off_trail = prior is not None and self.trail.distance(pos, cov) > self.chi(d)
        if (est.alarm or off_trail) and int((~np.isnan(z)).sum()) >= model.min_sensors:
            # Confirmed only if no p - s readings agree on a position where the vehicle can be (the trail).
            level = agreeing(model, z, self.s, self.chi_confirm, pos, known, prior, self.n_iter)
            if level.passing.any():
                j = level.best()
                support = level.masks[j] & ~np.isnan(z)  # a coasting filter's own support may be empty
                # The estimator's answer is judged by the agreeing fit's covariance alone when it raised the
                # alarm: by its own account it could not tell whom to trust, so its covariance (a coasting
                # filter's grows without bound) says nothing about where its answer is.
                own = np.zeros((d, d)) if est.alarm else cov
                if off_trail or _mahalanobis(pos - level.pos[j], level.cov[j] + own) > self.chi_confirm(d):
                    # Within tolerance after all, but the estimator's own answer is not where the agreeing
                    # readings put the vehicle (a least-bad filter after an attack): theirs is the output.
                    pos, cov, used = level.pos[j], level.cov[j], support
                    self._replace(est, pos, cov, used)
            else:
                found = explain(model, z, self.s, self.chi, pos, known, prior, self.n_iter)
                named = found.named
                object.__setattr__(est, "valid", False)
                object.__setattr__(est, "ambiguous", found.tied)
                object.__setattr__(est, "alarm", True)  # confirmed beyond tolerance, whoever noticed first
                if found.pos is not None and found.cov is not None:
                    pos, cov, used = found.pos, found.cov, found.used
                    self._replace(est, pos, cov, used)
                elif (held := self.trail.hold()) is not None:
                    # No single explanation this step: hold the last known position rather than output a fit
                    # the readings have just shown to be beyond tolerance.
                    pos, cov, used = held[0], held[1], np.zeros(model.p, dtype=bool)
                    self._replace(est, pos, cov, used)
                support = used
        within, fix, fix_cov = self.namer.name(z, support, pos, cov, known)  # every step
        if est.valid or support.any():  # a valid output, or an explanation (not a coast on the trail itself)
            # The readings' own fit where they agree (a filter's output lags in a turn), else the output.
            self.trail.correct(pos if fix is None else fix, cov if fix_cov is None else fix_cov, est.t_s)
        # Beyond tolerance a reading is named when every fewest-liars explanation leaves it out AND it fails the
        # same family-wise tests against the explanation's fit: with small biases the fewest liars can be the
        # wrong ones, and then the tests keep honest readings from being accused.
        accused = within if named is None else named & within
        object.__setattr__(est, "attacked", _indices(accused))
        self.accused[self.accused_k % EVIDENCE_STEPS] = accused
        self.accused_k += 1
        if est.valid and not self.model.within_tolerance(self.accused.sum(axis=0) >= EVIDENCE_MIN, self.s):
            # Evidence that builds up: more than s readings each named on several of the last steps lie
            # together, whichever s of them this step's readings let the estimator leave out. The answer stays
            # (it is the best the readings of this step allow); the claim that it can be trusted does not.
            object.__setattr__(est, "valid", False)
        if est.valid and self.mirrors and self._tie(z, est.position_m, known):
            object.__setattr__(est, "valid", False)
            object.__setattr__(est, "ambiguous", True)

    def _guard(self, est: Estimate) -> None:
        """Hold the output to the envelope (estimators.envelope): a valid output outside it, or from a filter that
        has lost track, is an alarm and the estimator starts again; a degraded one is only held inside it."""
        env = self.envelope
        assert env is not None
        inside = env.allows(est.position_m, est.t_s)
        if not est.valid:
            # Already degraded by its own account: a large covariance is honest then, and its trail and evidence
            # (what it knows about the attack) must not be thrown away; only where it is reported is held.
            if not inside:
                object.__setattr__(est, "position_m", env.project(est.position_m, est.t_s))
                object.__setattr__(est, "alarm", True)
            return
        if inside and not env.lost(est.covariance, self.model.d):
            env.accept(est.position_m, est.t_s)
            return
        object.__setattr__(est, "position_m", env.project(est.position_m, est.t_s))
        object.__setattr__(est, "velocity_mps", None)  # a diverged filter's velocity says nothing
        object.__setattr__(est, "covariance", None)
        object.__setattr__(est, "valid", False)
        object.__setattr__(est, "alarm", True)
        object.__setattr__(est, "reinitialised", True)
        last = (env.last_pos, env.last_t)
        # What a calibration told the tests (estimators.noise) outlives the restart.
        vif, confirm, band = self.namer.window_vif, self.namer.confirm_steps, self.namer.band
        drift = getattr(self, "drift", None)
        drift_vif = getattr(drift, "vif", None)
        self.reset()  # from the next readings, as at the first step; the motion bound keeps its anchor point
        self.t_s = est.t_s
        env.last_pos, env.last_t = last
        # The next cold fix starts its search at the last valid position, not amid the anchors: outside a
        # small anchor box the ranges' near-mirror image across the anchors is a second minimum, and a search
        # from the box's middle can land there and stay (Hanyang: least squares and the EKF 10-18 m off for
        # 4-7 s after one restart). The vehicle is within the motion bound of that position; its mirror is not.
        self.restart_pos = None if last[0] is None else np.array(last[0], dtype=float)
        self.namer.window_vif, self.namer.confirm_steps, self.namer.band = vif, confirm, band
        if drift_vif is not None and hasattr(getattr(self, "drift", None), "vif"):
            self.drift.vif = drift_vif

    def _tie(self, z: np.ndarray, pos: np.ndarray, known: Known) -> bool:
        """Whether the output's mirror image across a line or plane of anchors explains the readings with no more
        liars than the output, which leaves at least one unexplained (a reading is a liar when it fails its gate,
        family-wise at alpha / 10 per step)."""
        model = self.model
        sig2, gate = model.sigma_m**2, sidak_gate(self.alpha / 10.0, model.p)
        sep = 4.0 * float(np.max(model.sigma_m))

        def liars(x: np.ndarray) -> int:
            r = z - model.h(x, known)
            return int(np.sum(np.where(np.isnan(r), False, r * r > gate * sig2)))

        mine = None
        for mirror in self.mirrors:
            alt = mirror.reflect(pos)
            if np.linalg.norm(alt - pos) <= sep or np.linalg.norm(model.clip(alt) - alt) > 1e-9:
                continue  # the mirror is where the output is, or where the vehicle cannot be
            mine = liars(pos) if mine is None else mine
            if mine == 0:
                # Every reading fits the output: nothing lies, and the prior picks the side (on the ground before
                # take-off the laser has no reading yet and the coplanar anchors' mirror is 2 m up).
                return False
            if liars(alt) <= mine:
                return True
        return False

    def _replace(self, est: Estimate, pos: np.ndarray, cov: np.ndarray, used: np.ndarray) -> None:
        """Make ``est`` another fit's answer: its position and covariance, the trail's velocity, its readings."""
        object.__setattr__(est, "position_m", np.array(pos, dtype=float))
        object.__setattr__(est, "covariance", np.array(cov, dtype=float))
        object.__setattr__(est, "velocity_mps", self.trail.velocity())
        object.__setattr__(est, "used", _indices(used))

    # -- for subclasses ---------------------------------------------------
    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        raise NotImplementedError

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        raise NotImplementedError

    def _initial_cov(self) -> np.ndarray:
        d = self.model.d
        return np.diag([self.p0_pos_m**2] * d + [self.p0_vel_mps**2] * d)

    def _motion(self, bank: EkfBank) -> None:
        """Feed this step's velocity input, if any, to every filter of ``bank`` (after its prediction)."""
        if self.velocity_in is not None and self.velocity_std_mps is not None:
            bank.update_velocity(self.velocity_in, self.velocity_std_mps**2)

    def _cv(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        return cv_matrices(self.model.d, dt_s, self.q_axes)

    def _snapshot_fix(
        self, z: np.ndarray, use: np.ndarray, start: np.ndarray | None, known: Known, n_iter: int | None = None
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Weighted LS fix on the sensors in ``use``: (position, covariance, cost)."""
        if start is None:  # a cold start: after a restart, from the last valid position (``_guard``)
            start = self.model.initial_guess(z, known) if self.restart_pos is None else self.restart_pos
        res = gauss_newton(self.model, z, use[None, :], start, known, self.n_iter if n_iter is None else n_iter)
        cov = inv_small(res.info[0])
        return res.pos[0], cov, float(res.cost[0])

    def _flag_resid(self, resid: np.ndarray, jac: np.ndarray, cov_pos: np.ndarray) -> np.ndarray:
        """The same test from residuals and Jacobian already at hand (NaN residual: not flagged)."""
        var = self.model.sigma_m**2 + np.einsum("pd,de,pe->p", jac, cov_pos, jac)
        return resid * resid / var > self.gate1

    def _studentised(self, resid: np.ndarray, jac: np.ndarray, cov: np.ndarray, use: np.ndarray) -> np.ndarray:
        """Normalised squared residuals against a fit on ``use`` (NaN readings: 0).

        A reading inside the fit pulled the fit toward itself, so it is judged by
        its deleted residual ``r / (1 - l)`` (leverage ``l = H C H^T / sigma^2``);
        one outside by ``r^2 / (sigma^2 (1 + l))``.
        """
        sig2 = self.model.sigma_m**2
        lever = np.einsum("pd,de,pe->p", jac, cov, jac) / sig2
        scale = np.where(use, np.maximum(1.0 - lever, 1e-6), 1.0 + lever)
        t = resid * resid / (sig2 * scale)
        return np.where(np.isnan(t), 0.0, t)

    def make_estimate(
        self,
        t_s: float,
        position: np.ndarray | None,
        *,
        velocity: np.ndarray | None = None,
        covariance: np.ndarray | None = None,
        used: np.ndarray | frozenset[int] | None = None,
        attacked: np.ndarray | frozenset[int] | set[int] | list[int] | tuple[int, ...] = (),
        alarm: bool = False,
        valid: bool = True,
    ) -> Estimate:
        """One step's answer, for a ``_step`` to return (the public way; a plugin needs nothing private).

        ``position``: the model's d entries (None or NaN: no estimate yet, ``ok`` False). ``covariance`` over the
        position (d x d) or position and velocity (2d x 2d). ``used``, ``attacked``: the readings the answer rests
        on and the ones the method itself names as attacked, as indices into z or a boolean mask of length p.
        ``alarm``: the method says the readings are inconsistent; ``valid`` False: it says its answer is degraded.
        ``attacked`` and ``alarm`` are the method's own claim (recorded as ``own_*`` when the class ``detects``);
        with the shared attribution on (``+attribution`` rows) ``attacked`` is replaced by the attribution's names.
        """
        p, d = self.model.p, self.model.d
        ok = position is not None and bool(np.isfinite(np.asarray(position, dtype=float)).all())
        return Estimate(
            t_s=float(t_s),
            position_m=np.full(d, np.nan) if position is None else np.array(position, dtype=float).reshape(-1),
            velocity_mps=None if velocity is None else np.array(velocity, dtype=float),
            covariance=None if covariance is None else np.array(covariance, dtype=float),
            attacked=_as_indices(attacked, p),
            alarm=bool(alarm),
            step_time_s=0.0,
            used=frozenset() if used is None else _as_indices(used, p),
            ok=ok,
            valid=bool(valid),
        )

    def _estimate(
        self,
        t_s: float,
        pos: np.ndarray | None,
        vel: np.ndarray | None = None,
        cov: np.ndarray | None = None,
        alarm: bool = False,
        used: np.ndarray | None = None,
        nis: tuple[np.ndarray, np.ndarray] | None = None,
        which: int = 0,
    ) -> Estimate:
        """One step's answer; ``nis`` is an ``EkfBank.update`` result, of which filter ``which`` produced it."""
        d = self.model.d
        ok = pos is not None and bool(np.isfinite(pos).all())
        return Estimate(
            t_s=t_s,
            position_m=np.full(d, np.nan) if pos is None else np.array(pos, dtype=float),
            velocity_mps=None if vel is None else np.array(vel, dtype=float),
            covariance=None if cov is None else np.array(cov, dtype=float),
            attacked=frozenset(),  # named by _attribute for the secure estimators
            alarm=alarm,
            step_time_s=0.0,
            used=frozenset() if used is None else _indices(used),
            ok=ok,
            nis=None if nis is None or int(nis[1][which]) == 0 else (float(nis[0][which]), int(nis[1][which])),
        )

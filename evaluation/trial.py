"""One trial: fly, attack the streams with the attack_profiles engine, run every estimator.

Test case 1 (one vehicle with UWB): the anchor model with the downward laser as
one more reading (``anchor_model``: the height is estimated, and a spoofed laser
is a sensor attack like any other); error = horizontal position error. Test case 2 (two vehicles
ranging each other): the two-vehicle model; errors for the first vehicle's
position and for the inter-vehicle range. Wall hover (seed Fig. A.5, ReCaP's
setting; no UWB, a wall_distance target): the redundant rangefinder group as
one scalar; error = |estimated - true distance to the wall plane|. Ground truth for detection: a
reading the engine changed by more than ``5 sigma`` counts as attacked
(recall); any change counts for precision. The same estimators run on a
recorded log (:func:`evaluate` with ``from_log``, streams from
:mod:`evaluation.tlog`); see there how a log is scored.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from attack_profiles import Engine
from attack_profiles.profile import Profile
from estimators import aligned, noise
from estimators.aligned import ASYNC_PARAM
from estimators.base import Estimate, Estimator
from estimators.models import AnchorRangesHeight, Known, MeasurementModel, TwoVehicleRanges
from estimators.scenario_models import anchor_model, two_vehicle_model, wall_group_model
from evaluation.streams import Leg, VehicleStream, fly
from secuav_common.scenario import Scenario, WallDistanceTarget, with_noise_scale
from secuav_common.sensor_ids import anchor_sensor_id, peer_sensor_id

RATE_HZ = 10.0
Variants = Mapping[str, tuple[str, dict[str, Any]]]  # label -> (estimator name, its own parameters)
WARMUP_S = 1.0  # estimators' first second (start-up transient) is not scored


@dataclass(frozen=True, eq=False)
class EstimatorTrace:
    err_m: np.ndarray  # (T,) position error (first vehicle); NaN where there is no truth
    range_err_m: np.ndarray | None  # (T,) inter-vehicle range error (test case 2)
    est_xy_m: np.ndarray  # (T, 2) first vehicle's estimated north, east; (T, 1) wall distance
    step_time_s: np.ndarray  # (T,)
    named: np.ndarray  # (T, p) bool: judged attacked
    alarm: np.ndarray  # (T,) bool
    local_dev_m: np.ndarray | None = None  # (T,) distance from the autopilot's LOCAL_POSITION_NED (logs)
    # (T,) normalised estimation error squared e^T P^-1 e of the first vehicle's position (NaN without a
    # covariance or truth); a consistent estimator averages the number of position dimensions
    nees: np.ndarray | None = None
    degraded: np.ndarray | None = None  # (T,) bool: the estimate says it is not to be trusted (Estimate.valid False)
    height_err_m: np.ndarray | None = None  # (T,) |estimated - true down| where the model estimates the height
    # (T,) the output filter's normalised innovation squared per degree of freedom (Estimate.nis; NaN for
    # snapshot estimators); a consistent filter averages 1. Needs no truth, so it is also there on logs.
    nis: np.ndarray | None = None
    # The method's own claims (Estimate.own_attacked/own_alarm), None for a method that does not detect.
    own_named: np.ndarray | None = None  # (T, p) bool
    own_alarm: np.ndarray | None = None  # (T,) bool
    # What its calibration window did (estimators.noise.Calibrated.report: status, per-link readings, offsets,
    # scales); None without --calibrate.
    calibration: dict[str, Any] | None = None


def _own(est: Estimator | noise.Calibrated, shape: tuple[int, int]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Empty per-step arrays for the method's own claims, or (None, None) when it claims none."""
    if not (est.secure if est.detects is None else est.detects):
        return None, None
    return np.zeros(shape, dtype=bool), np.zeros(shape[0], dtype=bool)


def _record_own(out: Estimate, k: int, named: np.ndarray | None, alarm: np.ndarray | None) -> None:
    if named is not None and alarm is not None and out.own_attacked is not None:
        named[k, list(out.own_attacked)] = True
        alarm[k] = bool(out.own_alarm)


@dataclass(frozen=True, eq=False)
class TrialResult:
    t_s: np.ndarray
    truth_xy_m: np.ndarray  # (T, 2) first vehicle; (T, 1) wall distance in the wall case; NaN if unknown
    anchors_xy_m: np.ndarray
    offsets_m: np.ndarray  # (T, p) what the attack added (NaN where a reading was missing or dropped)
    sigma_m: np.ndarray  # (p,)
    sensor_ids: tuple[int, ...]
    traces: dict[str, EstimatorTrace]
    # A reading named attacked counts as rightly named (precision) when its offset exceeds this:
    # 0 when the offsets are exactly what an attack added; 3 sigma when they are deviations from truth.
    named_floor_m: np.ndarray | None = None
    scored_errors: bool = True  # False: no ground truth (a log without --truth)
    scored_detection: bool = True  # False: neither truth nor a known added attack
    local_xy_m: np.ndarray | None = None  # (T, 2) LOCAL_POSITION_NED of the first vehicle (logs)
    readings_m: np.ndarray | None = None  # (T, p) what the estimators read (attacked; NaN = missing)
    truth_down_m: np.ndarray | None = None  # (T,) the first vehicle's true NED down
    # (T, p) what this run's attack engine added to each reading (0 where it changed nothing, NaN where a
    # reading was missing); unlike offsets_m on a log, never the recording's own error. None: not known.
    added_m: np.ndarray | None = None
    # Steps at or before this time are not scored (the start-up transient; a calibration window, which is
    # not under test and must not count as attack-free time). See score_from().
    score_from_s: float = WARMUP_S
    # How each estimator (by label) took the readings: "sequential" or "aligned" (asynchronous, evaluate's
    # ``asynchronous``) or "synchronous" (the frames); and the asynchronous window (None when framed).
    processing: dict[str, str] | None = None
    async_window_s: float | None = None


def score_from(params: dict[str, Any] | None) -> float:
    """The first scored time: the warm-up, or the end of a calibration window (estimators.noise) plus the warm-up."""
    window = (params or {}).get(noise.CALIBRATION_PARAM)
    return WARMUP_S if window is None else float(window) + WARMUP_S


def _matrix(stream: VehicleStream, ids: list[int]) -> np.ndarray:
    n = stream.t_s.shape[0]
    return np.column_stack([stream.readings.get(i, np.full(n, np.nan)) for i in ids])


def _attack(engine: Engine | None, stream: VehicleStream, z: np.ndarray, ids: list[int]) -> np.ndarray:
    if engine is None:
        return z
    # A "vehicle" clock profile reads the boot clock; the live coordinated spoof tracks LOCAL_POSITION_NED,
    # so it sees what an attacker on the link reads: a log's LOCAL_POSITION_NED, a flight's vehicle estimate.
    t_s = stream.t_s + stream.boot_offset_s if engine.profile.clock == "vehicle" else stream.t_s
    position = next(p for p in (stream.local_ned_m, stream.attacker_view_ned_m, stream.truth_ned_m) if p is not None)
    return engine.apply_array(t_s, z, ids, sysid=stream.sysid, position_ned_m=position)


def _attacked_height(engine: Engine | None, stream: VehicleStream) -> VehicleStream:
    """The downward laser is a reading like any other: the attack acts on it before it becomes the height."""
    sid = stream.laser_down_id
    if engine is None or sid is None:
        return stream
    laser = _attack(engine, stream, stream.laser_down_m[:, None], [sid])[:, 0]  # unchanged unless a rule targets it
    return replace(stream, laser_down_m=laser)


def run_trial(
    scenario: Scenario,
    profile: Profile | None,
    names: list[str],
    seed: int,
    duration_s: float,
    leg: Leg,
    params: dict[str, Any] | None = None,
    dims: int = 3,
    variants: Variants | None = None,
    noise_scale: float = 1.0,
) -> TrialResult:
    """Fly the scenario headless (seeded), attack its streams offline, run the estimators (with ``params``).

    ``variants``: for an entry of ``names`` that is a label, the estimator it runs and the parameters of its own
    (over ``params``): a study's per-estimator grid, ``huber[huber_k=1.0]`` -> ``("huber", {"huber_k": 1.0})``.

    ``dims`` picks test case 1's model (``anchor_model``): 3 estimates the height with the laser as a
    reading, 2 takes the laser's height as known (the seed's split).

    ``noise_scale``: the flight's range sensors are that much noisier than the scenario says, while the
    estimators are still told the scenario's stds (a noise mismatch)."""
    flown = scenario if noise_scale == 1.0 else with_noise_scale(scenario, noise_scale)
    streams = fly(flown, seed, duration_s, RATE_HZ, leg)
    engine = None if profile is None else Engine(profile, seed=seed, scenario=scenario)
    return evaluate(scenario, streams, engine, names, params=params, dims=dims, variants=variants)


def evaluate(
    scenario: Scenario,
    streams: dict[int, VehicleStream],
    engine: Engine | None,
    names: list[str],
    *,
    from_log: bool = False,
    params: dict[str, Any] | None = None,
    dims: int = 3,
    variants: Variants | None = None,
    asynchronous: bool = False,
    window_s: float | None = None,
) -> TrialResult:
    """Run the estimators on framed streams (a headless flight, or a recorded log).

    ``asynchronous`` (a recording of one vehicle's anchor ranges): every estimator takes every reading at its own
    time instead of the frames (estimators.aligned: the EKF by sequential updates, the others on a window of
    ``window_s`` seconds, default ``aligned.default_window``, one frame period or the slowest link's reading interval
    when longer, brought to each frame time), and is scored at the frame times.
    Links too sparse for that window at that rate are refused (``SparseReadings``, option ``async_window_s``).

    From a flight the attack is the only thing that changes readings, so the
    offsets it added are known exactly. From a log the readings may already be
    attacked (recorded behind an attack): with truth, a reading's offset is its
    deviation from the range the true position implies; without truth, only an
    attack added here (``engine``) is known, and errors cannot be scored at all.
    """
    first = scenario.vehicles[0].sysid
    if scenario.kind == "wall":
        s1 = _attacked_height(engine, streams[first])
        check_readings(scenario, streams, dims, params, variants, from_log=from_log)
        wall = _wall_trial(scenario, s1, engine, names, from_log, params or {}, variants)
        return replace(wall, processing=processing_of(names, variants, None))
    inp = _inputs(scenario, streams, engine, dims)
    model, s1, z, clean, known, truth2 = inp.model, inp.s1, inp.z, inp.clean, inp.known, inp.truth2
    local = None if s1.local_ned_m is None else s1.local_ned_m[:, :2]
    raw, params = _checked_inputs(inp, engine, params, variants, from_log, asynchronous, window_s)
    window = None if raw is None else float(params[ASYNC_PARAM])
    traces = {
        name: _run_estimator(name, model, s1, z, known, truth2, local, params or {}, variants, raw)
        for name in names
    }  # fmt: skip
    n_anchor = len(scenario.anchor_positions())
    anchors = np.array([scenario.anchor_positions()[k] for k in sorted(scenario.anchor_positions())])[:n_anchor, :2]
    offsets, floor, scored_err, scored_det = _offsets(
        model, z, clean, engine, inp.truth_state, inp.truth_known, from_log
    )
    return TrialResult(
        t_s=s1.t_s,
        truth_xy_m=s1.truth_ned_m[:, :2],
        anchors_xy_m=anchors,
        offsets_m=offsets,
        sigma_m=model.sigma_m,
        sensor_ids=model.ids(),
        traces=traces,
        named_floor_m=floor,
        scored_errors=scored_err,
        scored_detection=scored_det,
        local_xy_m=local,
        readings_m=z,
        truth_down_m=s1.truth_ned_m[:, 2],
        added_m=z - clean,
        score_from_s=score_from(params),
        processing=processing_of(names, variants, window),
        async_window_s=window,
    )


def processing_of(names: list[str], variants: Variants | None, window_s: float | None) -> dict[str, str]:
    """Per label, how the estimator took the readings: ``sequential`` or ``aligned`` with an asynchronous window
    (estimators.aligned.processing), else ``synchronous`` (the frames)."""
    out = {}
    for label in names:
        name = (variants or {}).get(label, (label, {}))[0]
        out[label] = "synchronous" if window_s is None else aligned.processing(name)
    return out


def asynchronous_by_default(scenario: Scenario) -> bool:
    """Whether a recording of ``scenario`` is taken asynchronously unless framing is asked for (``secuav-eval``
    without ``--sync``, a study's recording without ``sync: true``): one vehicle ranging to anchors (test case 1).
    The formation and the wall group are framed."""
    return scenario.kind == "anchors"


@dataclass(frozen=True, eq=False)
class _Inputs:
    """What the estimators read (``z``, attacked), the clean readings, the known inputs and the truth to score."""

    model: MeasurementModel
    s1: VehicleStream
    z: np.ndarray
    clean: np.ndarray
    known: np.ndarray
    truth_state: np.ndarray
    truth_known: np.ndarray
    truth2: np.ndarray | None


def _inputs(scenario: Scenario, streams: dict[int, VehicleStream], engine: Engine | None, dims: int) -> _Inputs:
    """The readings matrix of test case 1 or 2 (not the wall group), attacked by ``engine`` (None: clean)."""
    first = scenario.vehicles[0].sysid
    clean_laser = streams[first].laser_down_m
    streams = {sysid: _attacked_height(engine, st) for sysid, st in streams.items()}
    s1 = streams[first]
    if scenario.kind == "formation":
        second = scenario.vehicles[1].sysid
        model: MeasurementModel = two_vehicle_model(scenario, first, second)
        anchor_ids = [k - 10 for k in model.sensor_ids[: model.n_anchors]]
        ids = [anchor_sensor_id(k) for k in anchor_ids]
        s2 = streams[second]
        z1 = _attack(engine, s1, _matrix(s1, [*ids, peer_sensor_id(second)]), [*ids, peer_sensor_id(second)])
        z2 = _attack(engine, s2, _matrix(s2, ids), ids)
        clean = np.hstack([_matrix(s1, ids), _matrix(s2, ids), _matrix(s1, [peer_sensor_id(second)])])
        z = np.hstack([z1[:, :-1], z2, z1[:, -1:]])
        known = np.column_stack([_height(s1), _height(s2)])
        truth2 = s2.truth_ned_m
        truth_state = np.hstack([s1.truth_ned_m[:, :2], truth2[:, :2]])
        truth_known = np.column_stack([s1.truth_ned_m[:, 2], truth2[:, 2]])
    else:
        model = anchor_model(scenario, first, dims)
        ids = list(model.sensor_ids)
        truth2 = None
        if isinstance(model, AnchorRangesHeight):
            # The downward laser is the last reading: attacked already (_attacked_height), like every reading.
            clean = np.column_stack([_matrix(s1, ids[:-1]), clean_laser])
            z = np.column_stack([_attack(engine, s1, clean[:, :-1], ids[:-1]), s1.laser_down_m])
            known = np.zeros((len(s1.t_s), 0))  # nothing is known: the height is estimated
            truth_state, truth_known = s1.truth_ned_m, np.zeros((len(s1.t_s), 1))
        else:
            clean = _matrix(s1, ids)
            z = _attack(engine, s1, clean, ids)
            known = _height(s1)[:, None]
            truth_state, truth_known = s1.truth_ned_m[:, :2], s1.truth_ned_m[:, 2:3]
    if known.shape[1]:
        # A missing laser reading: keep the last height (the model's default before the first one).
        known = _hold_last(known, np.asarray(model.default_known, dtype=float).reshape(-1))
    return _Inputs(model, s1, z, clean, known, truth_state, truth_known, truth2)


class SparseReadings(ValueError):
    """The readings are too sparse for the asked calibration window or framing rate (one line says which link).

    ``option``: what asked too much, ``calibration_s`` (with ``value`` the window) or ``rate_hz`` (the framing)."""

    def __init__(self, reason: str, option: str, value: float) -> None:
        super().__init__(reason)
        self.reason, self.option, self.value = reason, option, value

    def __reduce__(self) -> tuple[type, tuple[str, str, float]]:  # raised in a worker process (--jobs)
        return (SparseReadings, (self.reason, self.option, self.value))


def _windows(params: dict[str, Any] | None, variants: Variants | None, names: list[str] | None = None) -> list[float]:
    """Every calibration window asked for: the shared ``params``' and each variant's own."""
    asked = [(params or {}).get(noise.CALIBRATION_PARAM)]
    for label, (_, own) in (variants or {}).items():
        if names is None or label in names:
            asked.append({**(params or {}), **own}.get(noise.CALIBRATION_PARAM))
    return sorted({float(w) for w in asked if w is not None})


MIN_FIX_SHARE = 0.5  # framing: at least this share of the frames must hold the readings a fix needs


def _refuse_sparse(
    model: MeasurementModel,
    t_s: np.ndarray,
    z: np.ndarray,
    params: dict[str, Any] | None,
    variants: Variants | None,
    from_log: bool,
) -> None:
    """``SparseReadings`` when a calibration window or (for a recording) the framing rate asks for more readings
    than the links give; see docs/recorded-ranges.md ("Too sparse")."""
    ids = model.ids()
    for window in _windows(params, variants):
        reason = noise.count_window(model, t_s, z, window).refusal(ids)
        if reason is not None:
            raise SparseReadings(reason, noise.CALIBRATION_PARAM, window)
    if not from_log or t_s.size < 2:
        return
    have = np.isfinite(z)
    share = float(np.mean(have.sum(axis=1) >= model.min_sensors))
    if share >= MIN_FIX_SHARE:
        return
    rate = 1.0 / float(np.median(np.diff(t_s)))
    per_link = have.mean(axis=0) * rate  # readings per second each link brings into the frames
    # The fastest framing at which the average frame holds min_sensors readings (a link faster than the frames
    # fills every one of them): the largest R with sum_i min(1, r_i / R) >= min_sensors.
    best = 0.0
    for r in np.geomspace(0.01, rate, 400):
        if float(np.minimum(1.0, per_link / r).sum()) >= model.min_sensors:
            best = float(r)
    links = ", ".join(f"{sid}: {r:.2f}" for sid, r in zip(ids, per_link, strict=True))
    raise SparseReadings(
        f"framing at {rate:.3g} Hz: only {share:.0%} of the frames hold the {model.min_sensors} readings a fix "
        f"needs (needs {MIN_FIX_SHARE:.0%}); readings per second per link, sensor id: rate, {links}; "
        + (f"frame at {best:.2g} Hz or slower" if best > 0 else "too few links read at all"),
        "rate_hz",
        rate,
    )


def check_readings(
    scenario: Scenario,
    streams: dict[int, VehicleStream],
    dims: int,
    params: dict[str, Any] | None,
    variants: Variants | None = None,
    *,
    from_log: bool = True,
    asynchronous: bool = False,
    window_s: float | None = None,
) -> None:
    """Refuse (``SparseReadings``, one line naming the link and the numbers) streams too sparse for the asked
    calibration window, framing rate or (``asynchronous``) window, before any estimator runs (``secuav-eval``,
    a study's validation): the same checks :func:`evaluate` makes."""
    first = scenario.vehicles[0].sysid
    if scenario.kind == "wall":
        s1 = streams[first]
        model: MeasurementModel = wall_group_model(scenario, s1.sysid)
        target = scenario.vehicles[0].target
        assert isinstance(target, WallDistanceTarget)
        _refuse_sparse(model, s1.t_s, _matrix(s1, list(target.sensor_ids)), params, variants, from_log)
        return
    _checked_inputs(_inputs(scenario, streams, None, dims), None, params, variants, from_log, asynchronous, window_s)


def _checked_inputs(
    inp: _Inputs,
    engine: Engine | None,
    params: dict[str, Any] | None,
    variants: Variants | None,
    from_log: bool,
    asynchronous: bool,
    window_s: float | None,
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, dict[str, Any] | None]:
    """``SparseReadings`` when the readings are too sparse for what was asked; else the readings one at a time
    (``asynchronous``; None when framed) and ``params`` with the asynchronous window the estimators are built with."""
    model, t_s = inp.model, inp.s1.t_s
    if not asynchronous:
        _refuse_sparse(model, t_s, inp.z, params, variants, from_log)
        return None, params
    raw = _raw_inputs(inp, engine)
    window = async_window(t_s, window_s, _read_times(raw))
    _refuse_sparse_async(model, t_s, raw, window)
    params = {**(params or {}), ASYNC_PARAM: window}
    # The calibration window is counted on what the estimators will fit on: the readings at the frame times.
    _refuse_sparse(model, t_s, _aligned_counts(raw, t_s, window), params, variants, False)
    return raw, params


def _height(stream: VehicleStream) -> np.ndarray:
    """NED down of the vehicle: minus the downward laser; from a log, LOCAL_POSITION_NED's where the laser is silent."""
    z = -stream.laser_down_m
    if stream.local_ned_m is not None:
        z = np.where(np.isnan(z), stream.local_ned_m[:, 2], z)
    return z


def _offsets(
    model: MeasurementModel,
    z: np.ndarray,
    clean: np.ndarray,
    engine: Engine | None,
    truth_state: np.ndarray,
    truth_known: np.ndarray,
    from_log: bool,
) -> tuple[np.ndarray, np.ndarray | None, bool, bool]:
    """(offsets, named floor, errors scored, detection scored); see :func:`evaluate`."""
    has_truth = bool(np.isfinite(truth_state).all(axis=1).any())
    if not from_log:
        return z - clean, None, True, True
    if has_truth:
        expected = np.full(z.shape, np.nan)
        for k in np.flatnonzero(np.isfinite(truth_state).all(axis=1) & np.isfinite(truth_known).all(axis=1)):
            kn = float(truth_known[k, 0]) if truth_known.shape[1] == 1 else truth_known[k]
            expected[k] = model.h(truth_state[k], None if isinstance(model, AnchorRangesHeight) else kn)
        return z - expected, 3.0 * model.sigma_m, True, True
    return z - clean, None, False, engine is not None


def _hold_last(values: np.ndarray, default: np.ndarray) -> np.ndarray:
    out = values.copy()
    last = default.copy()
    for k in range(out.shape[0]):
        bad = np.isnan(out[k])
        out[k, bad] = last[bad]
        last = out[k].copy()
    return out


def _run_estimator(
    name: str,
    model: MeasurementModel,
    s1: VehicleStream,
    z: np.ndarray,
    known: np.ndarray,
    truth2: np.ndarray | None,
    local: np.ndarray | None = None,
    params: dict[str, Any] | None = None,
    variants: Variants | None = None,
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> EstimatorTrace:
    est = _create(name, model, params or {}, variants)
    feed = None if raw is None else _async_feed(est, *raw)
    own_named, own_alarm = _own(est, z.shape)
    n = z.shape[0]
    err = np.full(n, np.nan)
    rerr = None if truth2 is None else np.full(n, np.nan)
    xy = np.full((n, 2), np.nan)
    times = np.zeros(n)
    named = np.zeros(z.shape, dtype=bool)
    alarm = np.zeros(n, dtype=bool)
    nees, nis = np.full(n, np.nan), np.full(n, np.nan)
    degraded = np.zeros(n, dtype=bool)
    herr = np.full(n, np.nan) if isinstance(model, AnchorRangesHeight) else None
    for k in range(n):
        kn = None if known.shape[1] == 0 else float(known[k, 0]) if known.shape[1] == 1 else known[k]
        vel = None if s1.velocity_ned_m_s is None else s1.velocity_ned_m_s[k]
        if feed is None:
            out = est.step(float(s1.t_s[k]), z[k], kn, velocity=vel)
            times[k] = out.step_time_s
        else:
            out, times[k] = feed(float(s1.t_s[k]), z[k], kn, vel)
        alarm[k], degraded[k] = out.alarm, not out.valid
        named[k, list(out.attacked)] = True
        _record_own(out, k, own_named, own_alarm)
        pos = out.position_m
        xy[k] = pos[:2]
        err[k] = float(np.linalg.norm(pos[:2] - s1.truth_ned_m[k, :2]))
        nees[k] = _nees(pos[:2] - s1.truth_ned_m[k, :2], out.covariance)
        nis[k] = _nis(out)
        if herr is not None:
            herr[k] = abs(float(pos[2]) - float(s1.truth_ned_m[k, 2]))
        if truth2 is not None and rerr is not None:
            est_range = np.sqrt(np.sum((pos[0:2] - pos[2:4]) ** 2) + (kn[0] - kn[1]) ** 2)
            true_range = float(np.linalg.norm(s1.truth_ned_m[k] - truth2[k]))
            rerr[k] = abs(est_range - true_range)
    dev = None if local is None else np.linalg.norm(xy - local, axis=1)
    return EstimatorTrace(err, rerr, xy, times, named, alarm, dev, nees, degraded, herr, nis, own_named, own_alarm,
                          _calibration(est))  # fmt: skip


def async_window(t_s: np.ndarray, window_s: float | None, read_times: Sequence[np.ndarray] = ()) -> float:
    """The asynchronous window: as given, else :func:`estimators.aligned.default_window` (one output period, or
    the slowest link's reading interval when that is longer, up to ``aligned.COVER_MAX_S``)."""
    if window_s is not None:
        return float(window_s)
    return aligned.default_window(t_s, read_times)


def _read_times(raw: tuple[np.ndarray, np.ndarray, np.ndarray]) -> list[np.ndarray]:
    t, z, _ = raw
    return [t[np.isfinite(z[:, i])] for i in range(z.shape[1])]


def _refuse_sparse_async(
    model: MeasurementModel, t_s: np.ndarray, raw: tuple[np.ndarray, np.ndarray, np.ndarray], window_s: float
) -> None:
    """``SparseReadings`` when windows of ``window_s`` at the frame times leave a link (or the fix) too often empty."""
    cov = aligned.coverage(_read_times(raw), t_s, window_s, model.min_sensors)
    reason = cov.refusal(model.ids())
    if reason is not None:
        raise SparseReadings(reason, ASYNC_PARAM, window_s)


def _aligned_counts(raw: tuple[np.ndarray, np.ndarray, np.ndarray], t_s: np.ndarray, window_s: float) -> np.ndarray:
    """(T, p): 1 where the window ending at frame k holds a reading of the link (what the aligned step reads), else
    NaN: the calibration window's counts on the asynchronous input."""
    out = np.full((t_s.size, raw[1].shape[1]), np.nan)
    for i, ts in enumerate(_read_times(raw)):
        if ts.size:
            k = np.searchsorted(ts, t_s, side="right") - 1
            ok = k >= 0
            held = np.zeros(t_s.size, dtype=bool)
            held[ok] = t_s[ok] - ts[k[ok]] < window_s
            out[held, i] = 1.0
    return out


def _raw_inputs(inp: _Inputs, engine: Engine | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every reading of the first vehicle at its own time: (times (N,), readings (N, p) with NaN where a sensor did
    not read at that time, known inputs (N, k) held from the frame the time falls in), attacked by ``engine``."""
    s1, model = inp.s1, inp.model
    if s1.raw is None or isinstance(model, TwoVehicleRanges):
        raise ValueError("asynchronous processing needs one vehicle's recorded ranges (--ranges or --tlog)")
    ids = list(model.ids())
    laser = s1.laser_down_id if isinstance(model, AnchorRangesHeight) else None
    cols = [laser if (laser is not None and i == len(ids) - 1) else sid for i, sid in enumerate(ids)]
    series = [s1.raw.get(sid, (np.zeros(0), np.zeros(0))) if sid is not None else (np.zeros(0), np.zeros(0))
              for sid in cols]  # fmt: skip
    t = np.unique(np.concatenate([ts for ts, _ in series])) if series else np.zeros(0)
    z = np.full((t.size, len(ids)), np.nan)
    for j, (ts, vs) in enumerate(series):
        z[np.searchsorted(t, ts), j] = vs
    z[~(z >= 0.0)] = np.nan  # missing or negative readings, as framed
    if engine is not None:
        clock = t + s1.boot_offset_s if engine.profile.clock == "vehicle" else t
        frames = next(p for p in (s1.local_ned_m, s1.attacker_view_ned_m, s1.truth_ned_m) if p is not None)
        where = np.column_stack([np.interp(t, s1.t_s, frames[:, c]) for c in range(3)])
        anchors = len(ids) - (1 if laser is not None else 0)
        z[:, :anchors] = engine.apply_array(clock, z[:, :anchors], ids[:anchors], sysid=s1.sysid, position_ned_m=where)
    frame = np.clip(np.searchsorted(s1.t_s, t - 1e-9), 0, s1.t_s.size - 1)  # the frame each reading falls in
    return t, z, inp.known[frame]


def _async_feed(
    est: Estimator | noise.Calibrated | aligned.AsyncEstimator,
    t_raw: np.ndarray,
    z_raw: np.ndarray,
    known_raw: np.ndarray,
) -> Callable[[float, np.ndarray, Known, np.ndarray | None], tuple[Estimate, float]]:
    """Hand ``est`` (built with ``async_window_s``) every reading up to each frame time at its own time
    (``read``), then ask for the estimate at the frame time (``step`` without readings)."""
    state = {"j": 0}
    reader = getattr(est, "read", None)
    if reader is None:
        raise TypeError(f"{est.name} takes no asynchronous readings (built without async_window_s)")

    def known_at(j: int) -> Known:
        return None if known_raw.shape[1] == 0 else float(known_raw[j, 0]) if known_raw.shape[1] == 1 else known_raw[j]

    def feed(t_s: float, framed: np.ndarray, kn: Known, vel: np.ndarray | None) -> tuple[Estimate, float]:
        j = state["j"]
        while j < t_raw.size and t_raw[j] <= t_s + 1e-9:
            reader(float(t_raw[j]), z_raw[j], known_at(j))
            j += 1
        state["j"] = j
        out = est.step(t_s, None, kn, velocity=vel)
        return out, out.step_time_s

    return feed


def _calibration(est: Estimator | noise.Calibrated) -> dict[str, Any] | None:
    return est.report() if isinstance(est, noise.Calibrated) else None


def _create(
    label: str, model: MeasurementModel, params: dict[str, Any], variants: Variants | None
) -> Estimator | noise.Calibrated:
    """The estimator a name or a variant label stands for, with the shared ``params`` and its own over them
    (``estimators.noise.create``: ``estimators.create`` plus a calibration window when the params ask for one)."""
    name, own = (variants or {}).get(label, (label, {}))
    return noise.create(name, model, **{**shared_params(name, params), **own})


def shared_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """The shared parameters an estimator gets: all of them, except the vehicle's motion input
    (``velocity_std_mps``) for a method without one (``ls`` and the snapshot methods run without it, as the
    baselines every study compares with do; listed with its own params they still refuse it)."""
    from estimators import registry

    if "velocity_std_mps" in params and not registry.get(name).motion_input:
        return {k: v for k, v in params.items() if k != "velocity_std_mps"}
    return params


def _nis(out: Estimate) -> float:
    """The output filter's NIS per degree of freedom this step; NaN when there is none."""
    return np.nan if out.nis is None else out.nis[0] / out.nis[1]


def _nees(error: np.ndarray, cov: np.ndarray | None) -> float:
    """``e^T P^-1 e`` over the first ``len(e)`` states (the position block); NaN when it cannot be formed."""
    d = error.shape[0]
    if cov is None or cov.shape[0] < d or not np.isfinite(error).all():
        return float("nan")
    block = cov[:d, :d]
    try:
        return float(error @ np.linalg.solve(block, error))
    except np.linalg.LinAlgError:
        return float("nan")


def _wall_trial(
    scenario: Scenario,
    s1: VehicleStream,
    engine: Engine | None,
    names: list[str],
    from_log: bool,
    params: dict[str, Any],
    variants: Variants | None = None,
) -> TrialResult:
    target = scenario.vehicles[0].target
    assert isinstance(target, WallDistanceTarget)
    model = wall_group_model(scenario, s1.sysid)
    ids = list(target.sensor_ids)
    clean = _matrix(s1, ids)
    z = _attack(engine, s1, clean, ids)
    wall = scenario.wall(target.wall)
    # Distance to the plane along its normal (the group faces the wall while holding).
    true_d = (s1.truth_ned_m - np.asarray(wall.point_ned_m)) @ np.asarray(wall.normal_ned)
    traces = {}
    for name in names:
        est = _create(name, model, params, variants)
        own_named, own_alarm = _own(est, z.shape)
        n = z.shape[0]
        d_est, times = np.full(n, np.nan), np.zeros(n)
        named, alarm = np.zeros(z.shape, dtype=bool), np.zeros(n, dtype=bool)
        nees, nis, degraded = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=bool)
        for k in range(n):
            vel = None if s1.velocity_ned_m_s is None else s1.velocity_ned_m_s[k]
            out = est.step(float(s1.t_s[k]), z[k], velocity=vel)
            d_est[k], times[k], alarm[k], degraded[k] = out.position_m[0], out.step_time_s, out.alarm, not out.valid
            named[k, list(out.attacked)] = True
            _record_own(out, k, own_named, own_alarm)
            nees[k] = _nees(np.array([d_est[k] - true_d[k]]), out.covariance)
            nis[k] = _nis(out)
        traces[name] = EstimatorTrace(
            np.abs(d_est - true_d), None, d_est[:, None], times, named, alarm, None, nees, degraded, None, nis,
            own_named, own_alarm, _calibration(est),
        )
    offsets, floor, scored_err, scored_det = _offsets(
        model, z, clean, engine, true_d[:, None], np.zeros((z.shape[0], 1)), from_log
    )
    return TrialResult(
        t_s=s1.t_s,
        truth_xy_m=true_d[:, None],
        anchors_xy_m=np.zeros((0, 2)),
        offsets_m=offsets,
        sigma_m=model.sigma_m,
        sensor_ids=model.ids(),
        traces=traces,
        named_floor_m=floor,
        scored_errors=scored_err,
        scored_detection=scored_det,
        added_m=z - clean,
        score_from_s=score_from(params),
    )

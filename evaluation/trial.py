"""One trial: fly, attack the streams with the attack_profiles engine, run every estimator.

Test case 1 (one vehicle with UWB): the 2-D anchor model, height known from the
downward laser; error = horizontal position error. Test case 2 (two vehicles
ranging each other): the two-vehicle model; errors for the first vehicle's
position and for the inter-vehicle range. Wall hover (seed Fig. A.5, ReCaP's
setting; no UWB, a wall_distance target): the redundant rangefinder group as
one scalar; error = |estimated - true distance to the wall plane|. Ground truth for detection: a
reading the engine changed by more than ``5 sigma`` counts as attacked
(recall); any change counts for precision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import estimators
from attack_profiles import Engine
from attack_profiles.profile import Profile
from estimators.models import MeasurementModel
from estimators.scenario_models import anchor_model, two_vehicle_model, wall_group_model
from evaluation.streams import Leg, VehicleStream, fly
from secuav_common.scenario import Scenario, WallDistanceTarget
from secuav_common.sensor_ids import anchor_sensor_id, peer_sensor_id

RATE_HZ = 10.0
WARMUP_S = 1.0  # estimators' first second (start-up transient) is not scored


@dataclass(frozen=True, eq=False)
class EstimatorTrace:
    err_m: np.ndarray  # (T,) position error (first vehicle)
    range_err_m: np.ndarray | None  # (T,) inter-vehicle range error (test case 2)
    est_xy_m: np.ndarray  # (T, 2) first vehicle's estimated north, east; (T, 1) wall distance
    step_time_s: np.ndarray  # (T,)
    named: np.ndarray  # (T, p) bool: judged attacked
    alarm: np.ndarray  # (T,) bool


@dataclass(frozen=True, eq=False)
class TrialResult:
    t_s: np.ndarray
    truth_xy_m: np.ndarray  # (T, 2) first vehicle; (T, 1) wall distance in the wall case
    anchors_xy_m: np.ndarray
    offsets_m: np.ndarray  # (T, p) what the attack added (NaN where a reading was missing or dropped)
    sigma_m: np.ndarray  # (p,)
    sensor_ids: tuple[int, ...]
    traces: dict[str, EstimatorTrace]


def is_wall(scenario: Scenario) -> bool:
    first = scenario.vehicles[0]
    return first.sensors.uwb is None and isinstance(first.target, WallDistanceTarget)


def is_formation(scenario: Scenario) -> bool:
    v = scenario.vehicles
    return len(v) >= 2 and all(x.sensors.uwb is not None and x.sensors.inter_vehicle is not None for x in v[:2])


def _matrix(stream: VehicleStream, ids: list[int]) -> np.ndarray:
    n = stream.t_s.shape[0]
    return np.column_stack([stream.readings.get(i, np.full(n, np.nan)) for i in ids])


def _attack(engine: Engine | None, stream: VehicleStream, z: np.ndarray, ids: list[int]) -> np.ndarray:
    if engine is None:
        return z
    return engine.apply_array(stream.t_s, z, ids, sysid=stream.sysid, true_pos_ned_m=stream.truth_ned_m)


def run_trial(
    scenario: Scenario, profile: Profile | None, names: list[str], seed: int, duration_s: float, leg: Leg
) -> TrialResult:
    streams = fly(scenario, seed, duration_s, RATE_HZ, leg)
    engine = None if profile is None else Engine(profile, seed=seed, scenario=scenario)
    first = scenario.vehicles[0].sysid
    s1 = streams[first]
    if is_formation(scenario):
        second = scenario.vehicles[1].sysid
        model: MeasurementModel = two_vehicle_model(scenario, first, second)
        anchor_ids = [k - 10 for k in model.sensor_ids[: model.n_anchors]]
        ids = [anchor_sensor_id(k) for k in anchor_ids]
        s2 = streams[second]
        z1 = _attack(engine, s1, _matrix(s1, [*ids, peer_sensor_id(second)]), [*ids, peer_sensor_id(second)])
        z2 = _attack(engine, s2, _matrix(s2, ids), ids)
        clean = np.hstack([_matrix(s1, ids), _matrix(s2, ids), _matrix(s1, [peer_sensor_id(second)])])
        z = np.hstack([z1[:, :-1], z2, z1[:, -1:]])
        known = np.column_stack([-s1.laser_down_m, -s2.laser_down_m])
        truth2 = s2.truth_ned_m
    elif is_wall(scenario):
        return _wall_trial(scenario, s1, engine, names)
    else:
        model = anchor_model(scenario, first)
        ids = list(model.sensor_ids)
        clean = _matrix(s1, ids)
        z = _attack(engine, s1, clean, ids)
        known = -s1.laser_down_m[:, None]
        truth2 = None
    # A missing laser reading: keep the last height (the model's default before the first one).
    known = _hold_last(known, np.asarray(model.default_known, dtype=float).reshape(-1))
    traces = {name: _run_estimator(name, model, s1, z, known, truth2) for name in names}
    n_anchor = len(scenario.anchor_positions())
    anchors = np.array([scenario.anchor_positions()[k] for k in sorted(scenario.anchor_positions())])[:n_anchor, :2]
    return TrialResult(
        t_s=s1.t_s,
        truth_xy_m=s1.truth_ned_m[:, :2],
        anchors_xy_m=anchors,
        offsets_m=z - clean,
        sigma_m=model.sigma_m,
        sensor_ids=model.ids(),
        traces=traces,
    )


def _hold_last(values: np.ndarray, default: np.ndarray) -> np.ndarray:
    out = values.copy()
    last = default.copy()
    for k in range(out.shape[0]):
        bad = np.isnan(out[k])
        out[k, bad] = last[bad]
        last = out[k].copy()
    return out


def _run_estimator(
    name: str, model: MeasurementModel, s1: VehicleStream, z: np.ndarray, known: np.ndarray, truth2: np.ndarray | None
) -> EstimatorTrace:
    est = estimators.create(name, model)
    n = z.shape[0]
    err = np.full(n, np.nan)
    rerr = None if truth2 is None else np.full(n, np.nan)
    xy = np.full((n, 2), np.nan)
    times = np.zeros(n)
    named = np.zeros(z.shape, dtype=bool)
    alarm = np.zeros(n, dtype=bool)
    for k in range(n):
        kn = float(known[k, 0]) if known.shape[1] == 1 else known[k]
        out = est.step(float(s1.t_s[k]), z[k], kn)
        times[k] = out.step_time_s
        alarm[k] = out.alarm
        named[k, list(out.attacked)] = True
        pos = out.position_m
        xy[k] = pos[:2]
        err[k] = float(np.linalg.norm(pos[:2] - s1.truth_ned_m[k, :2]))
        if truth2 is not None and rerr is not None:
            est_range = np.sqrt(np.sum((pos[0:2] - pos[2:4]) ** 2) + (kn[0] - kn[1]) ** 2)
            true_range = float(np.linalg.norm(s1.truth_ned_m[k] - truth2[k]))
            rerr[k] = abs(est_range - true_range)
    return EstimatorTrace(err, rerr, xy, times, named, alarm)


def _wall_trial(scenario: Scenario, s1: VehicleStream, engine: Engine | None, names: list[str]) -> TrialResult:
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
        est = estimators.create(name, model)
        n = z.shape[0]
        d_est, times = np.full(n, np.nan), np.zeros(n)
        named, alarm = np.zeros(z.shape, dtype=bool), np.zeros(n, dtype=bool)
        for k in range(n):
            out = est.step(float(s1.t_s[k]), z[k])
            d_est[k], times[k], alarm[k] = out.position_m[0], out.step_time_s, out.alarm
            named[k, list(out.attacked)] = True
        traces[name] = EstimatorTrace(np.abs(d_est - true_d), None, d_est[:, None], times, named, alarm)
    return TrialResult(
        t_s=s1.t_s,
        truth_xy_m=true_d[:, None],
        anchors_xy_m=np.zeros((0, 2)),
        offsets_m=z - clean,
        sigma_m=model.sigma_m,
        sensor_ids=model.ids(),
        traces=traces,
    )

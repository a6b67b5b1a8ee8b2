"""Measurement streams from a headless flightsim flight, framed at the UWB rate.

The vehicles take off and then either hover (the seed's test cases hold their
target) or fly a gentle moving leg (a sinusoidal north-east velocity of
amplitude ``MOVING_SPEED_M_S``, swinging about 1.6 m either side of the hold
point). Every reading the sensors produce is kept; a frame at time t holds,
per sensor id, the last reading in (t - period, t], NaN if none
(dropout, out of range, not due). Truth is sampled at the frame times.

Each frame also carries the vehicle's own velocity estimate (what
LOCAL_POSITION_NED vx, vy, vz report): flightsim's estimate (truth plus white
noise of 0.03 m/s) plus a slowly wandering error, first-order Gauss-Markov of
std ``VEL_DRIFT_STD_M_S`` and time constant ``VEL_DRIFT_TAU_S`` per axis, as an
IMU or optical-flow velocity drifts between corrections. The estimators' motion
input (``velocity_std_mps``) reads it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from flightsim.api import FlightMode, OffboardSetpoint
from flightsim.simulation import Simulation
from secuav_common.scenario import Scenario

Leg = Literal["hover", "moving"]
MOVING_SPEED_M_S = 0.5
MOVING_PERIOD_S = 20.0
VEL_DRIFT_STD_M_S = 0.05
VEL_DRIFT_TAU_S = 10.0


@dataclass(frozen=True, eq=False)
class VehicleStream:
    sysid: int
    t_s: np.ndarray  # (T,) seconds since the evaluation window began
    truth_ned_m: np.ndarray  # (T, 3); NaN where unknown (a log without a truth file)
    readings: dict[int, np.ndarray]  # wire sensor id -> (T,) metres, NaN = none in that frame
    laser_down_m: np.ndarray  # (T,) downward rangefinder (height), NaN if the vehicle has none
    local_ned_m: np.ndarray | None = None  # (T, 3) the autopilot's LOCAL_POSITION_NED (logs only), not truth
    boot_offset_s: float = 0.0  # vehicle boot time at t_s = 0 (logs; 0 for flights)
    # (T, 3) the position an attacker on the link reads (the vehicle's own estimate, what LOCAL_POSITION_NED
    # carries, noise and all); flights only (a log has local_ned_m)
    attacker_view_ned_m: np.ndarray | None = None
    laser_down_id: int | None = None  # DISTANCE_SENSOR id of the downward laser (attacked like any reading)
    velocity_ned_m_s: np.ndarray | None = None  # (T, 3) the vehicle's own velocity estimate (module docstring)
    # Logs only: every reading at its own time before framing, sensor id -> (times on this stream's clock, metres),
    # for the estimators that take readings one at a time (secuav-eval --async)
    raw: dict[int, tuple[np.ndarray, np.ndarray]] | None = None


def _altitude(scenario: Scenario, sysid: int) -> float:
    target = scenario.vehicle(sysid).target
    if target is None:
        return 2.5
    return -target.pos_ned_m[2] if hasattr(target, "pos_ned_m") else float(target.altitude_m)


def fly(
    scenario: Scenario, seed: int, duration_s: float, rate_hz: float, leg: Leg = "hover"
) -> dict[int, VehicleStream]:
    """Fly the scenario headless and return each vehicle's framed stream."""
    sim = Simulation(scenario, seed=seed)
    sim.take_off(altitude_m=_altitude(scenario, scenario.vehicles[0].sysid))
    for v in sim.vehicles.values():
        v.pop_readings()  # the climb is not part of the evaluation window
    t0 = sim.t_s
    period = 1.0 / rate_hz
    n_frames = round(duration_s * rate_hz)
    sysids = list(sim.vehicles)
    down = {
        s: next((r.id for r in scenario.vehicle(s).sensors.rangefinders if r.orientation == "down"), None)
        for s in sysids
    }
    truth = {s: np.zeros((n_frames, 3)) for s in sysids}
    seen = {s: np.zeros((n_frames, 3)) for s in sysids}
    vel = {s: np.zeros((n_frames, 3)) for s in sysids}
    drift_rng = np.random.default_rng([seed, 7])  # its own stream: the flight itself is unchanged
    keep = math.exp(-period / VEL_DRIFT_TAU_S)
    drift = {s: VEL_DRIFT_STD_M_S * drift_rng.standard_normal(3) for s in sysids}
    frames: dict[int, list[dict[int, float]]] = {s: [] for s in sysids}
    if leg == "moving":
        for v in sim.vehicles.values():
            v.offboard_setpoint(OffboardSetpoint(vel_m_s=(0.0, 0.0, 0.0), yaw_rad=0.0))
            v.set_mode(FlightMode.OFFBOARD)

    def steer(s: Simulation) -> None:
        tau = s.t_s - t0
        # cos: the position swings +-(speed * period / 2 pi) around the hold point instead of drifting off.
        speed = MOVING_SPEED_M_S * math.cos(2.0 * math.pi * tau / MOVING_PERIOD_S)
        for v in s.vehicles.values():
            v.offboard_setpoint(OffboardSetpoint(vel_m_s=(speed, speed, 0.0), yaw_rad=0.0))

    for k in range(n_frames):
        sim.run_until(t0 + (k + 1) * period, steer if leg == "moving" else None)
        for s, v in sim.vehicles.items():
            latest: dict[int, float] = {}
            for r in v.pop_readings():  # in time order: the last one of the frame wins
                latest[r.sensor_id] = r.distance_m
            frames[s].append(latest)
            truth[s][k] = v.truth.pos_ned_m
            seen[s][k] = v.estimate.pos_ned_m
            drift[s] = keep * drift[s] + VEL_DRIFT_STD_M_S * math.sqrt(1.0 - keep * keep) * drift_rng.standard_normal(3)
            vel[s][k] = np.asarray(v.estimate.vel_ned_m_s) + drift[s]
    t_rel = (np.arange(n_frames) + 1) * period
    out = {}
    for s in sysids:
        ids = sorted({i for f in frames[s] for i in f})
        readings = {i: np.array([f.get(i, np.nan) for f in frames[s]], dtype=float) for i in ids}
        laser = readings.pop(down[s]) if down[s] is not None and down[s] in readings else np.full(n_frames, np.nan)
        out[s] = VehicleStream(s, t_rel, truth[s], readings, laser, attacker_view_ned_m=seen[s], laser_down_id=down[s],
                               velocity_ned_m_s=vel[s])  # fmt: skip
    return out

"""Sensors on a flying vehicle: readings agree with the true geometry; telemetry is never raw truth."""

from __future__ import annotations

import itertools
import math
import statistics

from flightsim.api import OffboardSetpoint, State
from flightsim.simulation import Simulation
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import load_scenario, parse_scenario
from tests.support.flight_helpers import airborne


def test_wall_group_reads_the_distance_to_the_wall_within_noise_even_while_tilting() -> None:
    sim, v = airborne("wall_hover")
    v.pop_readings()
    residuals: dict[int, list[float]] = {i: [] for i in range(6)}
    max_pitch = 0.0

    def check(_s: Simulation) -> None:
        nonlocal max_pitch
        tr = v.truth
        max_pitch = max(max_pitch, abs(tr.euler_rad[1]))
        for r in v.pop_readings():
            if not math.isnan(r.distance_m):
                mount = (0.0, 0.0, 1.0) if r.sensor_id == 5 else (1.0, 0.0, 0.0)
                residuals[r.sensor_id].append((r.distance_m - _expected(tr, mount)) / r.noise_std_m)

    # Swing back and forth between 1 and 3 m from the wall so the vehicle pitches.
    for target_n in (2.0, 4.0, 2.0):
        sp = OffboardSetpoint(pos_ned_m=(target_n - 0.0, 0.0, -2.5), yaw_rad=0.0)
        v.offboard_setpoint(sp)
        v.set_mode(v.mode.OFFBOARD)
        sim.run_for(3.0, lambda s, sp=sp: (v.offboard_setpoint(sp), check(s)))
    assert max_pitch > math.radians(5)
    for sid, z in residuals.items():
        assert len(z) > 50, sid
        # Normalised residuals: zero mean, unit spread (readings are sampled at the current truth).
        assert abs(statistics.fmean(z)) < 0.5, sid
        assert 0.7 < statistics.pstdev(z) < 1.3, sid


def _expected(tr: State, mount_body: tuple[float, float, float]) -> float:
    """Distance along the mounted beam to the wall (north, x = 5) or the ground (z = 0), by hand."""
    roll, pitch, yaw = tr.euler_rad
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    rot = (  # body -> NED, aerospace ZYX
        (cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
        (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
        (-sp, sr * cp, cr * cp),
    )
    d = [sum(rot[i][j] * mount_body[j] for j in range(3)) for i in range(3)]
    x, _, z = tr.pos_ned_m
    to_wall = (5.0 - x) / d[0] if d[0] > 0 else math.inf
    to_ground = -z / d[2] if d[2] > 0 else math.inf
    return min(to_wall, to_ground)


def test_anchor_and_peer_ids_in_formation() -> None:
    sim = Simulation(load_scenario("formation"))
    sim.run_for(1.0)
    for sysid, peer in ((1, 2), (2, 1)):
        ids = {r.sensor_id for r in sim.vehicles[sysid].pop_readings()}
        assert ids == {0} | set(range(10, 18)) | {50 + peer}
    sim.run_for(0.1)
    v1, v2 = sim.vehicles[1], sim.vehicles[2]
    peer_readings = [r for r in v1.pop_readings() if r.sensor_id == 52]
    assert peer_readings
    true_d = math.dist(v1.truth.pos_ned_m, v2.truth.pos_ned_m)
    assert abs(peer_readings[-1].distance_m - true_d) < 5 * 0.10


def test_estimate_and_gps_are_noisy_truth_with_the_configured_spread() -> None:
    sim, v = airborne("anchors8")
    v.pop_gps()
    errs_est: list[tuple[float, float, float]] = []
    errs_gps: list[tuple[float, float, float]] = []

    def collect(_s: Simulation) -> None:
        tr, est = v.truth, v.estimate
        errs_est.append(tuple(e - t for e, t in zip(est.pos_ned_m, tr.pos_ned_m, strict=True)))  # type: ignore[arg-type]
        for fix in v.pop_gps():
            n, e, d = geodetic_to_ned(v.home, fix.lat_deg, fix.lon_deg, fix.alt_m)
            errs_gps.append((n - tr.pos_ned_m[0], e - tr.pos_ned_m[1], d - tr.pos_ned_m[2]))

    sim.run_for(20.0, collect)
    assert len(errs_gps) == 200  # 10 Hz
    assert v.estimate.pos_ned_m != v.truth.pos_ned_m
    assert v.estimate.vel_ned_m_s != v.truth.vel_ned_m_s
    assert v.estimate.quat != v.truth.quat
    # Scenario: horizontal 0.05 m, vertical 0.08 m; the white part alone is 0.6 x that on a fix.
    for axis, std in ((0, 0.05), (1, 0.05), (2, 0.08)):
        white = [b[axis] - a[axis] for a, b in itertools.pairwise(errs_gps)]
        assert 0.6 * std * math.sqrt(2) * 0.7 < statistics.pstdev(white) < 0.6 * std * math.sqrt(2) * 1.3
        assert max(abs(e[axis]) for e in errs_est) < 6 * std


def test_start_heading_turns_the_forward_beam() -> None:
    text = """
name: east-wall
world:
  walls: [{name: east, point_ned_m: [0.0, 3.0, 0.0], normal_ned: [0.0, -1.0, 0.0]}]
vehicles:
  - sysid: 1
    start: {pos_ned_m: [1.0, 0.0, 0.0], yaw_deg: 90}
    sensors:
      rangefinders: [{id: 0, orientation: forward, noise_std_m: 0.0}]
"""
    sim = Simulation(parse_scenario(text))
    sim.run_for(0.5)
    v = sim.vehicles[1]
    assert abs(v.truth.euler_rad[2] - math.pi / 2) < 0.01
    assert math.dist(v.truth.pos_ned_m, (1.0, 0.0, 0.0)) < 0.01
    d = [r.distance_m for r in v.pop_readings()]
    assert abs(d[-1] - 3.0) < 0.02

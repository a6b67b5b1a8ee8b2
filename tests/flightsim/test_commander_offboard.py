"""Offboard control as PX4 does it: only with a live setpoint stream, failsafe when it stops."""

from __future__ import annotations

import math

from flightsim.api import FlightMode, LandedState, OffboardSetpoint, Result
from flightsim.simulation import Simulation
from secuav_common.scenario import load_scenario
from tests.support.flight_helpers import airborne, fly_offboard, texts


def test_offboard_refused_without_a_setpoint_stream() -> None:
    sim, v = airborne()
    outcome = v.set_mode(FlightMode.OFFBOARD)
    assert outcome.result == Result.TEMPORARILY_REJECTED
    assert "offboard" in outcome.reason.lower()
    assert v.mode == FlightMode.HOLD
    v.offboard_setpoint(OffboardSetpoint(pos_ned_m=(2.5, 2.5, -2.5)))
    sim.run_for(1.0)  # the one setpoint is now stale
    assert not v.set_mode(FlightMode.OFFBOARD).ok


def test_offboard_position_ned_with_yaw() -> None:
    sim, v = airborne()
    target = (3.5, 1.5, -3.0)
    fly_offboard(sim, v, OffboardSetpoint(pos_ned_m=target, yaw_rad=math.radians(90)), 8.0)
    assert math.dist(v.truth.pos_ned_m, target) < 0.2
    assert abs(v.truth.euler_rad[2] - math.radians(90)) < 0.05


def test_offboard_velocity_ned() -> None:
    sim, v = airborne()
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(0.0, 1.0, 0.0), yaw_rad=0.0), 3.0)
    vel = v.truth.vel_ned_m_s
    assert abs(vel[0]) < 0.1 and abs(vel[1] - 1.0) < 0.1 and abs(vel[2]) < 0.1
    assert abs(v.truth.pos_ned_m[2] + 2.5) < 0.25


def test_offboard_body_velocity_follows_the_heading() -> None:
    sim, v = airborne()
    # Face east first, then "forward" in the body frame must be east in NED.
    fly_offboard(sim, v, OffboardSetpoint(pos_ned_m=(2.5, 2.5, -2.5), yaw_rad=math.radians(90)), 4.0)
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(1.0, 0.0, 0.0), yaw_rate_rad_s=0.0, frame="body"), 3.0)
    vel = v.truth.vel_ned_m_s
    assert abs(vel[1] - 1.0) < 0.12 and abs(vel[0]) < 0.12


def test_offboard_yaw_rate_turns() -> None:
    sim, v = airborne()
    yaw0 = v.truth.euler_rad[2]
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.5, frame="body"), 2.0)
    turned = (v.truth.euler_rad[2] - yaw0) % (2 * math.pi)
    assert 0.7 < turned < 1.1


def test_offboard_position_plus_velocity_feed_forward() -> None:
    sim, v = airborne()
    # A point moving north at 0.5 m/s, given as position + velocity, as MAVSDK's set_position_velocity_ned.
    t0 = sim.t_s
    start = v.estimate.pos_ned_m

    def moving(_s: Simulation) -> None:
        dt = sim.t_s - t0
        v.offboard_setpoint(OffboardSetpoint(pos_ned_m=(start[0] + 0.5 * dt, 2.5, -2.5), vel_m_s=(0.5, 0.0, 0.0)))

    moving(sim)
    assert v.set_mode(FlightMode.OFFBOARD).ok
    sim.run_for(4.0, moving)
    expected_n = start[0] + 0.5 * (sim.t_s - t0)
    assert abs(v.estimate.pos_ned_m[0] - expected_n) < 0.1
    assert abs(v.truth.vel_ned_m_s[0] - 0.5) < 0.1


def test_loss_of_offboard_in_air_holds_with_a_status_text() -> None:
    sim, v = airborne()
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(0.5, 0.0, 0.0), yaw_rad=0.0), 2.0)
    texts(v)
    sim.run_for(0.8)  # under COM_OF_LOSS_T = 1 s: still offboard
    assert v.mode == FlightMode.OFFBOARD
    sim.run_for(0.4)
    assert v.mode == FlightMode.HOLD
    assert any("offboard" in t.lower() and "hold" in t.lower() for t in texts(v))
    sim.run_for(4.0)
    assert math.hypot(*v.truth.vel_ned_m_s[:2]) < 0.1
    assert v.armed and v.landed_state == LandedState.IN_AIR


def test_loss_of_offboard_on_the_ground_lands_and_disarms() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    v.offboard_setpoint(OffboardSetpoint(vel_m_s=(0.0, 0.0, 0.0), yaw_rad=0.0))
    assert v.set_mode(FlightMode.OFFBOARD).ok
    assert v.arm().ok
    sim.run_for(1.5)
    assert v.mode == FlightMode.LAND
    assert any("activating Land" in t for t in texts(v))
    sim.run_for(3.0)
    assert not v.armed


def test_offboard_takeoff_from_the_ground_with_a_climb_setpoint() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    sp = OffboardSetpoint(pos_ned_m=(2.5, 2.5, -2.0), yaw_rad=0.0)
    v.offboard_setpoint(sp)
    assert v.set_mode(FlightMode.OFFBOARD).ok
    assert v.arm().ok
    fly_offboard(sim, v, sp, 6.0)
    assert v.landed_state == LandedState.IN_AIR
    assert abs(v.truth.pos_ned_m[2] + 2.0) < 0.2

"""Crashes end the flight: wall contact, hard ground impact; and runs are reproducible."""

from __future__ import annotations

from flightsim.api import FlightMode, OffboardSetpoint, Result
from flightsim.simulation import Simulation
from secuav_common.scenario import load_scenario
from tests.support.flight_helpers import airborne, fly_offboard, texts


def test_flying_into_the_wall_is_a_crash_with_a_status_text() -> None:
    sim, v = airborne("wall_hover")
    texts(v)
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(1.5, 0.0, 0.0), yaw_rad=0.0), 5.0)
    assert v.crashed
    assert not v.armed
    assert v.physics.motors == (0.0, 0.0, 0.0, 0.0)
    said = texts(v)
    assert any(t.startswith("collision with wall 'wall' at 1.") for t in said), said
    # Stopped at the wall, not through it: the vehicle's radius is 0.25 m.
    assert 4.7 < v.truth.pos_ned_m[0] < 4.8
    assert v.truth.vel_ned_m_s == (0.0, 0.0, 0.0)
    assert v.set_mode(FlightMode.HOLD).result == Result.DENIED
    assert not v.health.prearm_ok


def test_motors_off_at_height_is_a_ground_crash() -> None:
    sim, v = airborne("anchors8")
    assert v.takeoff(4.0).ok
    sim.run_for(4.0)
    texts(v)
    assert v.disarm(force=True).ok
    sim.run_for(2.0)
    assert v.crashed
    said = texts(v)
    assert any(t.startswith("collision with the ground at") for t in said), said


def test_gentle_landing_is_no_crash() -> None:
    sim, v = airborne("anchors8")
    v.land()
    sim.run_for(8.0)
    assert not v.crashed and not v.armed


def _flight_log(seed: int | None) -> list[tuple[float, ...]]:
    sim = Simulation(load_scenario("formation"), seed=seed)
    for v in sim.vehicles.values():
        sim.run_for(0.1)
        v.arm()
        v.takeoff()
    sim.run_for(4.0)
    out = []
    for v in sim.vehicles.values():
        out.append(v.truth.pos_ned_m + v.estimate.pos_ned_m)
        out.append(tuple(r.distance_m for r in v.pop_readings()[-20:]))
    return out


def test_same_seed_same_flight_and_noise_other_seed_other_noise() -> None:
    a, b = _flight_log(None), _flight_log(None)
    assert a == b
    c = _flight_log(99)
    assert c != a


def test_two_vehicles_meeting_in_the_air_both_crash() -> None:
    sim = Simulation(load_scenario("formation"))
    sim.take_off()
    v1, v2 = sim.vehicles[1], sim.vehicles[2]
    meet = OffboardSetpoint(pos_ned_m=(2.5, 2.5, -2.5), yaw_rad=0.0)
    for v in (v1, v2):
        v.offboard_setpoint(meet)
        assert v.set_mode(FlightMode.OFFBOARD).ok
    sim.run_for(6.0, lambda _s: (v1.offboard_setpoint(meet), v2.offboard_setpoint(meet)))
    assert v1.crashed and v2.crashed
    assert any(t.startswith("collision with vehicle 2") for t in texts(v1))
    assert any(t.startswith("collision with vehicle 1") for t in texts(v2))

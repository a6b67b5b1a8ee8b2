"""Arming, disarming and mode refusals answer as PX4 would, with a reason."""

from __future__ import annotations

import math

from flightsim.api import FlightMode, LandedState, NavCommand, NavItem, OffboardSetpoint, Result
from flightsim.simulation import Simulation
from secuav_common.scenario import load_scenario
from tests.support.flight_helpers import airborne, fly_offboard, texts


def test_initial_state_is_disarmed_manual_on_ground() -> None:
    sim = Simulation(load_scenario("anchors8"))
    sim.run_for(0.2)
    v = sim.vehicles[1]
    assert not v.armed
    assert v.mode == FlightMode.MANUAL
    assert v.landed_state == LandedState.ON_GROUND
    assert v.health.prearm_ok and v.health.gps


def test_takeoff_refused_while_disarmed() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    out = v.takeoff()
    assert out.result == Result.DENIED and "arm" in out.reason
    assert ("Takeoff denied: disarmed, arm first") in texts(v)


def test_arming_refused_in_mission_mode_without_mission_and_mode_refused() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    assert v.set_mode(FlightMode.MISSION).result == Result.TEMPORARILY_REJECTED
    assert v.set_mission([NavItem(NavCommand.WAYPOINT, (2.5, 2.5, -2.0))]).ok
    assert v.set_mode(FlightMode.MISSION).ok
    assert v.set_mission([]).ok
    out = v.arm()
    assert out.result == Result.DENIED and out.reason == "Arming denied: no valid mission"
    assert not v.armed


def test_arming_refused_in_land_mode_and_after_a_crash() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    assert v.set_mode(FlightMode.LAND).ok
    assert v.arm().reason == "Arming denied: not possible in Land mode"
    v.commander.crash("collision with wall 'test' at 1.0 m/s")
    out = v.arm()
    assert out.result == Result.DENIED and "crashed" in out.reason
    assert not v.health.prearm_ok


def test_arming_refused_when_not_level() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    # Tip the vehicle on its side on the ground through JSBSim's initial conditions.
    fdm = v.physics._fdm
    fdm["ic/phi-deg"] = 45.0
    fdm.run_ic()
    sim.run_for(0.1)
    assert v.arm().reason == "Arming denied: vehicle not level"


def test_disarm_refused_in_air_unless_forced() -> None:
    _sim, v = airborne()
    out = v.disarm()
    assert out.result == Result.DENIED and out.reason == "Disarming denied: not landed"
    assert v.armed
    assert v.disarm(force=True).ok
    assert not v.armed


def test_preflight_auto_disarm_when_no_takeoff_follows() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    assert v.arm().ok
    sim.run_for(9.0)
    assert v.armed
    sim.run_for(1.5)
    assert not v.armed
    assert "Disarmed by auto preflight disarming" in texts(v)


def test_rtl_refused_on_the_ground_and_manual_refused_in_air() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    assert v.return_to_launch().result == Result.TEMPORARILY_REJECTED
    sim, v = airborne()
    assert v.set_mode(FlightMode.MANUAL).result == Result.TEMPORARILY_REJECTED
    assert v.set_mode(FlightMode.POSITION).ok


def test_params_validate_type_range_and_name() -> None:
    sim = Simulation(load_scenario("formation"))
    v = sim.vehicles[2]
    names = [p.name for p in v.params()]
    for required in (
        "MIS_TAKEOFF_ALT",
        "MPC_XY_VEL_MAX",
        "COM_OF_LOSS_T",
        "RTL_RETURN_ALT",
        "NAV_ACC_RAD",
        "SYS_AUTOSTART",
        "MAV_SYS_ID",
        "COM_RC_IN_MODE",
        "MPC_Z_VEL_MAX_UP",
        "MPC_Z_VEL_MAX_DN",
    ):
        assert required in names
    assert all(len(n) <= 16 for n in names)
    assert v.get_param("MAV_SYS_ID").value == 2 and v.get_param("MAV_SYS_ID").is_int  # type: ignore[union-attr]
    assert not v.get_param("MIS_TAKEOFF_ALT").is_int  # type: ignore[union-attr]
    assert v.get_param("NO_SUCH_PARAM") is None
    assert v.set_param("NO_SUCH_PARAM", 1.0) is None
    assert v.set_param("MPC_XY_VEL_MAX", -1.0) is None  # out of range: unchanged
    assert v.set_param("SYS_AUTOSTART", 4001.5) is None  # integer parameter
    assert v.set_param("MPC_XY_VEL_MAX", float("nan")) is None
    assert v.get_param("MPC_XY_VEL_MAX").value == 12.0  # type: ignore[union-attr]
    assert v.set_param("MPC_XY_VEL_MAX", 2.0).value == 2.0  # type: ignore[union-attr]


def test_xy_speed_limit_param_is_respected() -> None:
    sim, v = airborne()
    assert v.set_param("MPC_XY_VEL_MAX", 1.0) is not None
    top = 0.0

    def watch(_s: Simulation) -> None:
        nonlocal top
        top = max(top, math.hypot(*v.truth.vel_ned_m_s[:2]))

    far = OffboardSetpoint(pos_ned_m=(12.0, 2.5, -2.5))
    fly_offboard(sim, v, far, 1.0)
    sim.run_for(3.0, lambda s: (v.offboard_setpoint(far), watch(s)))
    assert 0.9 < top < 1.15


def test_every_param_marked_used_is_read_by_the_autopilot() -> None:
    import pathlib

    import flightsim
    from flightsim.params import SPECS

    root = pathlib.Path(flightsim.__file__).parent
    autopilot = ["commander.py", "navigator.py", "vehicle.py", "sensors.py", "simulation.py"]
    files = [root / f for f in autopilot] + list((root / "control").glob("*.py"))
    source = "".join(p.read_text() for p in files)
    for spec in SPECS:
        assert (f'"{spec.name}"' in source) == spec.used, spec.name

"""Flight behaviour on real JSBSim: takeoff, hover quality, steps, land, RTL, missions."""

from __future__ import annotations

import math
import statistics

from flightsim.api import FlightMode, LandedState, NavCommand, NavItem, OffboardSetpoint
from flightsim.simulation import Simulation
from secuav_common.scenario import load_scenario
from tests.support.flight_helpers import airborne, fly_offboard, texts


def test_takeoff_reaches_mis_takeoff_alt_within_20cm_and_hovers_still() -> None:
    sim, v = airborne()
    assert abs(-v.truth.pos_ned_m[2] - 2.5) < 0.2
    assert v.landed_state == LandedState.IN_AIR
    track: list[tuple[float, float, float]] = []
    sim.run_for(20.0, lambda _s: track.append(v.truth.pos_ned_m))
    for axis in range(3):
        assert statistics.pstdev(p[axis] for p in track) < 0.1
    # It holds where it took off (2.5, 2.5), not somewhere else.
    assert math.dist(track[-1][:2], (2.5, 2.5)) < 0.3


def test_takeoff_to_requested_altitude_and_param_change() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    v.arm()
    assert v.landed_state == LandedState.ON_GROUND
    assert v.takeoff(4.0).ok
    sim.run_for(1.0)
    assert v.landed_state == LandedState.TAKEOFF
    sim.run_for(9.0)
    assert abs(-v.truth.pos_ned_m[2] - 4.0) < 0.2
    assert v.set_param("MIS_TAKEOFF_ALT", 3.0) is not None
    assert v.takeoff().ok
    sim.run_for(6.0)
    assert abs(-v.truth.pos_ned_m[2] - 3.0) < 0.2


def test_position_step_is_crisp() -> None:
    sim, v = airborne()
    start_n = v.estimate.pos_ned_m[0]
    target = (start_n + 2.0, 2.5, -2.5)
    track: list[tuple[float, float]] = []
    v.offboard_setpoint(OffboardSetpoint(pos_ned_m=target, yaw_rad=0.0))
    assert v.set_mode(FlightMode.OFFBOARD).ok
    t0 = sim.t_s

    def stream(_s: Simulation) -> None:
        v.offboard_setpoint(OffboardSetpoint(pos_ned_m=target, yaw_rad=0.0))
        track.append((sim.t_s - t0, v.estimate.pos_ned_m[0]))

    sim.run_for(6.0, stream)
    overshoot = max(n for _, n in track) - target[0]
    rise_90 = min(t for t, n in track if n > start_n + 1.8)
    settled = max(t for t, n in track if abs(n - target[0]) > 0.1)
    assert overshoot < 0.15
    assert rise_90 < 2.0
    assert settled < 3.0


def test_land_detects_touchdown_then_disarms() -> None:
    sim, v = airborne()
    texts(v)
    assert v.land().ok
    sim.run_for(1.0)
    assert v.landed_state == LandedState.LANDING
    sim.run_for(9.0)
    assert v.landed_state == LandedState.ON_GROUND
    assert not v.armed
    assert not v.crashed
    assert abs(v.truth.pos_ned_m[2]) < 0.05
    said = texts(v)
    assert said.index("Landing detected") < said.index("Disarmed by landing")


def test_return_to_launch_climbs_flies_home_and_lands() -> None:
    sim, v = airborne()  # anchors8 starts at (2.5, 2.5), home is (0, 0)
    max_alt = 0.0

    def watch(_s: Simulation) -> None:
        nonlocal max_alt
        max_alt = max(max_alt, -v.truth.pos_ned_m[2])

    assert v.return_to_launch().ok
    assert v.mode == FlightMode.RTL
    sim.run_for(25.0, watch)
    assert abs(max_alt - v.get_param("RTL_RETURN_ALT").value) < 0.4  # type: ignore[union-attr]
    assert math.hypot(*v.truth.pos_ned_m[:2]) < 0.3
    assert v.landed_state == LandedState.ON_GROUND
    assert not v.armed


def test_mission_of_three_waypoints_from_the_ground() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    wps = [(2.5, 2.5, -3.0), (4.0, 2.5, -3.0), (4.0, 4.0, -2.0)]
    assert v.set_mission([NavItem(NavCommand.WAYPOINT, p, hold_s=0.5) for p in wps]).ok
    assert v.set_mode(FlightMode.MISSION).ok
    assert v.arm().ok
    visited: list[int] = []
    closest = [math.inf] * 3

    def watch(_s: Simulation) -> None:
        i = v.mission_current
        if not visited or visited[-1] != i:
            visited.append(i)
        closest[i] = min(closest[i], math.dist(v.truth.pos_ned_m, wps[i]))

    sim.run_for(25.0, watch)
    assert visited == [0, 1, 2]
    assert v.mission_finished
    assert all(d < 0.6 for d in closest)
    assert math.dist(v.truth.pos_ned_m, wps[2]) < 0.25
    assert v.mode == FlightMode.MISSION


def test_mission_ending_with_land_disarms() -> None:
    sim, v = airborne()
    items = [NavItem(NavCommand.WAYPOINT, (3.5, 2.5, -2.5)), NavItem(NavCommand.LAND, (3.5, 3.5, 0.0))]
    assert v.set_mission(items).ok
    assert v.set_mode(FlightMode.MISSION).ok
    sim.run_for(20.0)
    assert not v.armed
    assert math.dist(v.truth.pos_ned_m[:2], (3.5, 3.5)) < 0.3
    assert v.mission_finished


def test_headless_take_off_of_a_formation() -> None:
    sim = Simulation(load_scenario("formation"))
    sim.take_off(3.0)
    for sysid, v in sim.vehicles.items():
        start = sim.scenario.vehicle(sysid).start.pos_ned_m
        assert math.dist(v.truth.pos_ned_m, (start[0], start[1], -3.0)) < 0.3
    sim.run_for(5.0)
    assert all(v.mode == FlightMode.HOLD and not v.crashed for v in sim.vehicles.values())


def test_nan_fields_of_an_offboard_setpoint_are_not_poison() -> None:
    sim, v = airborne()
    nan = math.nan
    # Altitude only (north/east not controlled), NaN yaw = keep heading.
    fly_offboard(sim, v, OffboardSetpoint(pos_ned_m=(nan, nan, -3.5), yaw_rad=nan), 5.0)
    assert abs(v.truth.pos_ned_m[2] + 3.5) < 0.2
    fly_offboard(sim, v, OffboardSetpoint(vel_m_s=(nan, 0.5, 0.0)), 3.0)
    assert abs(v.truth.vel_ned_m_s[1] - 0.5) < 0.1
    # Garbage: infinities in position and acceleration fields.
    fly_offboard(sim, v, OffboardSetpoint(pos_ned_m=(math.inf, 2.0, -2.5), acc_m_s2=(math.inf, 0.0, -math.inf)), 3.0)
    assert v.reposition((math.inf, -math.inf, -3.0)).ok
    sim.run_for(3.0)
    assert all(math.isfinite(c) for c in v.truth.pos_ned_m)
    assert not v.crashed and abs(v.truth.pos_ned_m[2] + 3.0) < 0.25


def test_vertical_speed_limits_hold_on_a_big_altitude_step() -> None:
    sim, v = airborne()
    up_max = v.get_param("MPC_Z_VEL_MAX_UP").value  # type: ignore[union-attr]
    dn_max = v.get_param("MPC_Z_VEL_MAX_DN").value  # type: ignore[union-attr]
    vz: list[float] = []
    high = OffboardSetpoint(pos_ned_m=(2.5, 2.5, -10.0), yaw_rad=0.0)
    low = OffboardSetpoint(pos_ned_m=(2.5, 2.5, -2.5), yaw_rad=0.0)
    fly_offboard(sim, v, high, 0.0)
    sim.run_for(6.0, lambda _s: (v.offboard_setpoint(high), vz.append(v.truth.vel_ned_m_s[2])))
    assert up_max * 0.9 < -min(vz) < up_max * 1.1
    vz.clear()
    sim.run_for(8.0, lambda _s: (v.offboard_setpoint(low), vz.append(v.truth.vel_ned_m_s[2])))
    assert dn_max * 0.9 < max(vz) < dn_max * 1.1


def test_reposition_flies_there_and_holds() -> None:
    sim, v = airborne()
    assert v.reposition((4.0, 1.0, math.nan), math.radians(45)).ok
    assert v.mode == FlightMode.HOLD
    sim.run_for(6.0)
    assert math.dist(v.truth.pos_ned_m[:2], (4.0, 1.0)) < 0.2
    assert abs(v.truth.pos_ned_m[2] + 2.5) < 0.2  # NaN altitude: kept
    assert abs(v.truth.euler_rad[2] - math.radians(45)) < 0.05
    ground = Simulation(load_scenario("anchors8"))
    assert not ground.vehicles[1].reposition((1.0, 1.0, -2.0)).ok  # on the ground, disarmed


def test_mission_with_takeoff_loiter_and_rtl_items() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    items = [
        NavItem(NavCommand.TAKEOFF, (2.5, 2.5, -3.0)),
        NavItem(NavCommand.LOITER_TIME, (3.5, 2.5, -3.0), hold_s=2.0),
        NavItem(NavCommand.RETURN_TO_LAUNCH, (0.0, 0.0, 0.0)),
    ]
    assert v.set_mission(items).ok
    assert v.set_mode(FlightMode.MISSION).ok
    assert v.arm().ok
    sim.run_for(1.0)
    assert v.landed_state == LandedState.TAKEOFF
    peak = 0.0
    at_loiter: list[float] = []
    events: list[tuple[int, FlightMode]] = []

    def watch(_s: Simulation) -> None:
        nonlocal peak
        peak = max(peak, -v.truth.pos_ned_m[2])
        if not events or events[-1] != (v.mission_current, v.mode):
            events.append((v.mission_current, v.mode))
        if v.mission_current == 1 and math.dist(v.truth.pos_ned_m, (3.5, 2.5, -3.0)) < 0.55:
            at_loiter.append(sim.t_s)

    sim.run_for(35.0, watch)
    assert events[:3] == [(0, FlightMode.MISSION), (1, FlightMode.MISSION), (2, FlightMode.MISSION)]
    assert (2, FlightMode.RTL) in events
    assert abs(peak - max(3.0, v.get_param("RTL_RETURN_ALT").value)) < 0.25  # type: ignore[union-attr]
    assert at_loiter and at_loiter[-1] - at_loiter[0] >= 1.9  # loitered its 2 s
    assert not v.armed
    assert math.hypot(*v.truth.pos_ned_m[:2]) < 0.3


def test_mission_legs_face_the_next_waypoint_unless_the_item_sets_a_yaw() -> None:
    sim, v = airborne()
    items = [
        NavItem(NavCommand.WAYPOINT, (2.5, 5.0, -2.5)),  # due east
        NavItem(NavCommand.WAYPOINT, (0.5, 5.0, -2.5)),  # due south
        NavItem(NavCommand.WAYPOINT, (0.5, 3.0, -2.5), yaw_rad=0.0),  # west, but told to face north
    ]
    assert v.set_mission(items).ok
    assert v.set_mode(FlightMode.MISSION).ok
    # (heading, bearing from the vehicle to its waypoint) per leg
    headings: dict[int, list[tuple[float, float]]] = {0: [], 1: [], 2: []}

    def watch(_s: Simulation) -> None:
        goal = items[v.mission_current].pos_ned_m
        n, e, _ = v.truth.pos_ned_m
        if not v.mission_finished and math.dist((n, e), goal[:2]) > 1.0:
            headings[v.mission_current].append((v.truth.euler_rad[2], math.atan2(goal[1] - e, goal[0] - n)))

    sim.run_for(20.0, watch)
    assert v.mission_finished

    def err(pair: tuple[float, float]) -> float:
        return abs(math.remainder(pair[0] - pair[1], 2 * math.pi))

    for i in (0, 1):
        # Each leg starts with the nose ~90 deg off, then turns to face the waypoint.
        assert err(headings[i][0]) > 1.0, i
        assert min(err(h) for h in headings[i]) < 0.1, i
    assert abs(math.remainder(v.truth.euler_rad[2], 2 * math.pi)) < 0.05  # the last item's own yaw wins

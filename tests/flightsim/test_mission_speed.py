"""Mission legs fly at the speed their DO_CHANGE_SPEED item set (MAVSDK's per-item speed), else MPC_XY_CRUISE."""

from __future__ import annotations

import math

from flightsim.api import FlightMode, NavCommand, NavItem
from flightsim.simulation import Simulation
from tests.support.flight_helpers import airborne

MID_N = 4.5  # the legs run between north 2.5 and 6.5


def _mid_leg_peaks(legs: list[NavItem], seconds: float) -> list[float]:
    sim, v = airborne("anchors8")
    assert v.set_mission(legs).ok
    assert v.set_mode(FlightMode.MISSION).ok
    peaks = [0.0] * len(legs)

    def watch(_s: Simulation) -> None:
        # mid-leg only: the end of one leg still carries the speed of the one before
        tr = v.truth
        if abs(tr.pos_ned_m[0] - MID_N) < 0.6:
            i = min(v.mission_current, len(legs) - 1)
            peaks[i] = max(peaks[i], math.hypot(tr.vel_ned_m_s[0], tr.vel_ned_m_s[1]))

    sim.run_for(seconds, watch)
    assert v.mission_finished
    return peaks


def test_legs_fly_at_their_item_speed_and_default_to_cruise() -> None:
    here = (2.5, 2.5, -2.5)
    legs = [
        NavItem(NavCommand.WAYPOINT, (here[0] + 4.0, here[1], -2.5)),  # MPC_XY_CRUISE (5 m/s) caps it
        NavItem(NavCommand.WAYPOINT, (here[0], here[1], -2.5), speed_m_s=1.0),
        NavItem(NavCommand.WAYPOINT, (here[0] + 4.0, here[1], -2.5), speed_m_s=30.0),  # MPC_XY_VEL_MAX caps it
    ]
    peaks = _mid_leg_peaks(legs, 20.0)
    assert peaks[0] > 2.0
    assert 0.8 < peaks[1] < 1.15
    assert peaks[2] > 2.0


def test_a_change_speed_command_beats_item_and_cruise_speeds_until_reset() -> None:
    legs = [
        NavItem(NavCommand.WAYPOINT, (6.5, 2.5, -2.5)),
        NavItem(NavCommand.WAYPOINT, (2.5, 2.5, -2.5), speed_m_s=3.0),
    ]
    sim, v = airborne("anchors8")
    assert v.set_cruise_speed(1.2).ok
    assert not v.set_cruise_speed(float("nan")).ok and not v.set_cruise_speed(-3.0).ok
    assert v.set_mission(legs).ok and v.set_mode(FlightMode.MISSION).ok
    peaks = [0.0, 0.0]

    def watch(_s: Simulation) -> None:
        tr = v.truth
        if abs(tr.pos_ned_m[0] - MID_N) < 0.6:
            i = min(v.mission_current, 1)
            peaks[i] = max(peaks[i], math.hypot(tr.vel_ned_m_s[0], tr.vel_ned_m_s[1]))

    sim.run_for(14.0, watch)
    assert v.mission_finished
    assert all(1.0 < p < 1.35 for p in peaks), peaks
    assert v.set_cruise_speed(None).ok
    assert v.commander.nav.cruise_m_s(3.0) == 3.0 and v.commander.nav.cruise_m_s() == 5.0

"""Commander: arming, flight modes, land detection and failsafes, PX4-style.

It decides what the vehicle is allowed to do and in which mode it is; the
:class:`~flightsim.navigator.Navigator` decides where to fly in that mode.
Refusals carry the reason PX4 would print, and every notable event (mode
refusals, failsafes, takeoff/landing detected, auto-disarm, crash) is queued
as a (MAV_SEVERITY, text) status message.

Land detection stands in for PX4's thrust-and-acceleration detector with the
gear's weight-on-wheels (JSBSim contact) plus a still vertical estimate.

Motor output has three states: ``OFF`` (disarmed), ``IDLE`` (armed on the
ground with nothing asking to climb: props spin, controllers held in reset)
and ``FLY`` (the control cascade runs).
"""

from __future__ import annotations

import math
from enum import Enum

from flightsim.api import FlightMode, LandedState, NavItem, OffboardSetpoint, Outcome, Result, State
from flightsim.control import Setpoint
from flightsim.navigator import Guidance, Navigator, RtlPhase
from flightsim.params import Params

# MAV_SEVERITY values used in status texts
CRITICAL, WARNING, INFO = 2, 4, 6
OFFBOARD_STREAM_MAX_AGE_S = 0.5  # PX4 wants setpoints at >2 Hz before it switches to offboard
LAND_DETECT_S = 0.5  # contact and no vertical motion for this long = landed
TAKEOFF_DETECT_S = 0.2
MAX_ARM_TILT_RAD = math.radians(30.0)


class Motors(Enum):
    OFF = 0
    IDLE = 1
    FLY = 2


class Commander:
    def __init__(self, params: Params) -> None:
        self.p = params
        self.nav = Navigator(params)
        self.mode = FlightMode.MANUAL
        self.armed = False
        self.landed = True
        self.crashed = False
        self.takeoff_phase = False  # climbing after a takeoff command (landed state TAKEOFF)
        self.battery_low = False
        self.status: list[tuple[int, str]] = []
        self._offboard: OffboardSetpoint | None = None
        self._offboard_t_s = -math.inf
        self._armed_t_s = 0.0
        self._has_flown = False
        self._contact_t_s = 0.0  # how long the land detector has seen ground contact and no motion
        self._air_t_s = 0.0
        self._landed_t_s = 0.0
        self._est: State | None = None
        self._t_s = 0.0

    def observe(self, t_s: float, est: State) -> None:
        """Latest clock and estimate, so commands between control ticks act on fresh data."""
        self._t_s = t_s
        self._est = est

    # -- queries ------------------------------------------------------------------
    @property
    def landed_state(self) -> LandedState:
        if self.landed:
            return LandedState.ON_GROUND
        if self.takeoff_phase or (self.mode == FlightMode.MISSION and self.nav.mission_climbing):
            return LandedState.TAKEOFF
        landing = self.mode == FlightMode.LAND or (self.mode == FlightMode.RTL and self.nav.rtl_phase is RtlPhase.LAND)
        return LandedState.LANDING if landing else LandedState.IN_AIR

    def _say(self, severity: int, text: str) -> None:
        self.status.append((severity, text))

    def _deny(self, text: str, result: Result = Result.DENIED) -> Outcome:
        self._say(CRITICAL if result == Result.DENIED else WARNING, text)
        return Outcome(result, text)

    def _offboard_fresh(self, max_age_s: float) -> bool:
        return self._offboard is not None and self._t_s - self._offboard_t_s <= max_age_s

    # -- commands -----------------------------------------------------------------
    def arm(self) -> Outcome:
        if self.crashed:
            return self._deny("Arming denied: vehicle crashed, restart the simulation")
        if self.armed:
            return Outcome(Result.ACCEPTED)
        est = self._est
        if est is not None and math.hypot(est.euler_rad[0], est.euler_rad[1]) > MAX_ARM_TILT_RAD:
            return self._deny("Arming denied: vehicle not level")
        if self.battery_low:
            return self._deny("Arming denied: low battery")
        if self.mode in (FlightMode.LAND, FlightMode.RTL):
            return self._deny(f"Arming denied: not possible in {self.mode.value.capitalize()} mode")
        if self.mode == FlightMode.MISSION and not self.nav.mission:
            return self._deny("Arming denied: no valid mission")
        if self.mode == FlightMode.OFFBOARD and not self._offboard_fresh(self.p["COM_OF_LOSS_T"]):
            return self._deny("Arming denied: no offboard setpoints")
        self.armed = True
        self._armed_t_s = self._t_s
        self._has_flown = False
        self._say(INFO, "Armed by external command")
        if self.mode == FlightMode.TAKEOFF and est is not None:
            self._begin_takeoff(est, self.p["MIS_TAKEOFF_ALT"])
        elif self.mode == FlightMode.MISSION and est is not None:
            self.nav.start_mission(est, self.landed)
        return Outcome(Result.ACCEPTED)

    def disarm(self, force: bool = False, reason: str = "Disarmed by external command") -> Outcome:
        if not self.armed:
            return Outcome(Result.ACCEPTED)
        if not self.landed and not force:
            return self._deny("Disarming denied: not landed")
        self.armed = False
        self.takeoff_phase = False
        self._say(INFO, reason)
        return Outcome(Result.ACCEPTED)

    def takeoff(self, altitude_m: float | None) -> Outcome:
        if self.crashed:
            return self._deny("Takeoff denied: vehicle crashed")
        if not self.armed:
            return self._deny("Takeoff denied: disarmed, arm first")
        alt = self.p["MIS_TAKEOFF_ALT"] if altitude_m is None or math.isnan(altitude_m) else altitude_m
        if not 0.5 <= alt <= 120.0:
            return self._deny(f"Takeoff denied: altitude {alt:.1f} m outside 0.5..120 m")
        assert self._est is not None
        self.mode = FlightMode.TAKEOFF
        self._begin_takeoff(self._est, alt)
        return Outcome(Result.ACCEPTED)

    def _begin_takeoff(self, est: State, alt: float) -> None:
        self.nav.start_takeoff(est, alt)
        self.takeoff_phase = True

    def land(self) -> Outcome:
        if self.crashed:
            return self._deny("Land denied: vehicle crashed")
        assert self._est is not None
        self.mode = FlightMode.LAND
        self.takeoff_phase = False
        self.nav.start_land(self._est)
        return Outcome(Result.ACCEPTED)

    def return_to_launch(self) -> Outcome:
        if self.crashed:
            return self._deny("Return denied: vehicle crashed")
        if not self.armed or self.landed:
            return self._deny("Return denied: vehicle is on the ground", Result.TEMPORARILY_REJECTED)
        assert self._est is not None
        self.mode = FlightMode.RTL
        self.takeoff_phase = False
        self.nav.start_rtl(self._est)
        return Outcome(Result.ACCEPTED)

    def set_mode(self, mode: FlightMode) -> Outcome:
        if self.crashed:
            return self._deny("Mode change denied: vehicle crashed")
        if mode == self.mode:
            return Outcome(Result.ACCEPTED)
        est = self._est
        assert est is not None
        if mode == FlightMode.TAKEOFF:
            if self.armed:
                return self.takeoff(None)
            self.mode = mode
            return Outcome(Result.ACCEPTED)
        if mode == FlightMode.LAND:
            return self.land()
        if mode == FlightMode.RTL:
            return self.return_to_launch()
        if mode == FlightMode.MANUAL and not self.landed:
            return self._deny("Switching to Manual denied: no manual control input", Result.TEMPORARILY_REJECTED)
        if mode == FlightMode.MISSION:
            if not self.nav.mission:
                return self._deny("Switching to Mission denied: no mission uploaded", Result.TEMPORARILY_REJECTED)
            self.mode = mode
            if self.armed:
                self.nav.start_mission(est, self.landed)
            self.takeoff_phase = False
            return Outcome(Result.ACCEPTED)
        if mode == FlightMode.OFFBOARD and not self._offboard_fresh(OFFBOARD_STREAM_MAX_AGE_S):
            return self._deny("Switching to Offboard denied: no offboard setpoints", Result.TEMPORARILY_REJECTED)
        # HOLD, POSITION (no sticks: holds like HOLD), MANUAL on the ground, OFFBOARD.
        self.mode = mode
        self.takeoff_phase = False
        self.nav.start_hold(est)
        return Outcome(Result.ACCEPTED)

    def reposition(self, pos_ned_m: tuple[float, float, float], yaw_rad: float | None) -> Outcome:
        """MAV_CMD_DO_REPOSITION: fly to a point and hold there (mode Hold), as PX4."""
        if self.crashed:
            return self._deny("Reposition denied: vehicle crashed")
        if not self.armed or self.landed:
            return self._deny("Reposition denied: vehicle is on the ground", Result.TEMPORARILY_REJECTED)
        if not any(math.isfinite(c) for c in pos_ned_m) and (yaw_rad is None or not math.isfinite(yaw_rad)):
            return self._deny("Reposition denied: no position given")
        assert self._est is not None
        self.mode = FlightMode.HOLD
        self.takeoff_phase = False
        self.nav.start_reposition(self._est, pos_ned_m, yaw_rad)
        return Outcome(Result.ACCEPTED)

    def set_cruise_speed(self, speed_m_s: float | None) -> Outcome:
        """MAV_CMD_DO_CHANGE_SPEED: the horizontal speed of auto legs and repositions; None restores the default."""
        if speed_m_s is not None and not (math.isfinite(speed_m_s) and speed_m_s > 0):
            return self._deny(f"Change speed denied: {speed_m_s} m/s is not a speed")
        self.nav.speed_override_m_s = speed_m_s
        if self.nav.hold_xy_speed is not None:  # a reposition under way takes the new speed too
            self.nav.hold_xy_speed = self.nav.cruise_m_s()
        return Outcome(Result.ACCEPTED)

    def offboard_setpoint(self, setpoint: OffboardSetpoint) -> None:
        self._offboard = _sanitised(setpoint)
        self._offboard_t_s = self._t_s

    def set_mission(self, items: list[NavItem]) -> Outcome:
        for i, item in enumerate(items):
            if not all(math.isfinite(c) for c in item.pos_ned_m):
                return self._deny(f"Mission rejected: item {i} has no valid position")
        self.nav.mission = list(items)
        self.nav.jump_to(0)
        if self.mode == FlightMode.MISSION and self._est is not None and self.armed:
            self.nav.start_mission(self._est, self.landed)
        return Outcome(Result.ACCEPTED)

    def set_mission_current(self, seq: int) -> Outcome:
        if not 0 <= seq < max(1, len(self.nav.mission)):
            return self._deny(f"Mission item {seq} does not exist")
        self.nav.jump_to(seq)
        return Outcome(Result.ACCEPTED)

    def crash(self, text: str) -> None:
        if self.crashed:
            return
        self.crashed = True
        self.armed = False
        self.takeoff_phase = False
        self._say(CRITICAL, text)

    # -- per control tick ---------------------------------------------------------------
    def update(self, t_s: float, dt_s: float, est: State, contact: bool) -> tuple[Motors, Guidance | None]:
        """Advance land detection, failsafes and mode logic; return what the motors should do."""
        self.observe(t_s, est)
        self.nav.dt_s = dt_s
        self._detect_landing(dt_s, est, contact)
        self._failsafes(t_s, est)
        if not self.armed:
            self.nav.rest(est)
            return Motors.OFF, None
        guidance = self._guidance(est, t_s)
        if self.landed and not guidance.wants_climb:
            self.nav.rest(est)
            landing_done = self._has_flown or self.mode == FlightMode.LAND
            if landing_done and self._landed_t_s >= self.p["COM_DISARM_LAND"] >= 0:
                self.disarm(reason="Disarmed by landing")
                self._after_landing()
                return Motors.OFF, None
            if not self._has_flown and t_s - self._armed_t_s >= self.p["COM_DISARM_PRFLT"] > 0:
                self.disarm(reason="Disarmed by auto preflight disarming")
                return Motors.OFF, None
            return Motors.IDLE, guidance
        return Motors.FLY, guidance

    def _after_landing(self) -> None:
        if self.mode == FlightMode.MISSION:
            self.nav.mission_finished = True
        if self.mode in (FlightMode.LAND, FlightMode.RTL, FlightMode.MISSION, FlightMode.TAKEOFF):
            self.mode = FlightMode.HOLD

    def _detect_landing(self, dt_s: float, est: State, contact: bool) -> None:
        still = abs(est.vel_ned_m_s[2]) < self.p["LNDMC_Z_VEL_MAX"]
        if self.landed:
            self._landed_t_s += dt_s
            self._air_t_s = self._air_t_s + dt_s if not contact else 0.0
            if self._air_t_s >= TAKEOFF_DETECT_S and self.armed:
                self.landed = False
                self._has_flown = True
                self._contact_t_s = 0.0
                self._say(INFO, "Takeoff detected")
            return
        self._contact_t_s = self._contact_t_s + dt_s if (contact and still) else 0.0
        if self._contact_t_s >= LAND_DETECT_S or (not self.armed and contact):
            self.landed = True
            self._landed_t_s = 0.0
            self._air_t_s = 0.0
            self.takeoff_phase = False
            self._say(INFO, "Landing detected")

    def _failsafes(self, t_s: float, est: State) -> None:
        if self.mode == FlightMode.OFFBOARD and not self._offboard_fresh(self.p["COM_OF_LOSS_T"]):
            if self.landed:
                self.mode = FlightMode.LAND
                self.nav.start_land(est)
                self._say(WARNING, "Failsafe: offboard setpoints lost, activating Land")
            else:
                self.mode = FlightMode.HOLD
                self.nav.start_hold(est)
                self._say(WARNING, "Failsafe: offboard setpoints lost, activating Hold")

    def _guidance(self, est: State, t_s: float) -> Guidance:
        nav, mode = self.nav, self.mode
        nav.event = None
        if mode == FlightMode.TAKEOFF:
            g = nav.takeoff(est)
            if nav.event == "takeoff_done":
                self.takeoff_phase = False
                self.mode = FlightMode.HOLD
                nav.hold_pos = nav.target
        elif mode == FlightMode.LAND:
            g = nav.land(est)
        elif mode == FlightMode.RTL:
            g = nav.rtl(est)
        elif mode == FlightMode.MISSION:
            g = nav.mission_step(est, t_s)
            if nav.event == "mission_rtl":
                self.mode = FlightMode.RTL
                nav.start_rtl(est)
        elif mode == FlightMode.OFFBOARD and self._offboard is not None:
            g = self._offboard_guidance(self._offboard, est)
        else:
            g = nav.hold()
        return g

    def _offboard_guidance(self, sp: OffboardSetpoint, est: State) -> Guidance:
        vel, acc = sp.vel_m_s, sp.acc_m_s2
        if sp.frame == "body":
            yaw = est.euler_rad[2]
            c, s = math.cos(yaw), math.sin(yaw)
            if vel is not None:
                vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
            if acc is not None:
                acc = (c * acc[0] - s * acc[1], s * acc[0] + c * acc[1], acc[2])
        yaw_sp = sp.yaw_rad
        if yaw_sp is None and sp.yaw_rate_rad_s is None:
            yaw_sp = self.nav.yaw  # keep the heading we had
        else:
            self.nav.yaw = yaw_sp if yaw_sp is not None else est.euler_rad[2]
        setpoint = Setpoint(sp.pos_ned_m, vel, acc, yaw_sp, sp.yaw_rate_rad_s)
        climb = (
            (sp.pos_ned_m is not None and sp.pos_ned_m[2] < est.pos_ned_m[2] - 0.3)
            or (vel is not None and vel[2] < -0.2)
            or (acc is not None and acc[2] < -0.5)
        )
        p = self.p
        return Guidance(setpoint, p["MPC_XY_VEL_MAX"], p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"], climb)


def _sanitised(sp: OffboardSetpoint) -> OffboardSetpoint:
    """NaN handling as PX4's: a NaN (or infinite) position axis is "not controlled", a NaN yaw
    "keep heading", a NaN velocity or acceleration component zero (so a half-filled or garbled
    message cannot poison the loops)."""

    def zero_nan(v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        return None if v is None else (_num(v[0]), _num(v[1]), _num(v[2]))

    pos = sp.pos_ned_m
    if pos is not None:
        pos = (_nan_if_bad(pos[0]), _nan_if_bad(pos[1]), _nan_if_bad(pos[2]))
        if all(math.isnan(c) for c in pos):
            pos = None
    yaw = None if sp.yaw_rad is None or not math.isfinite(sp.yaw_rad) else sp.yaw_rad
    rate = None if sp.yaw_rate_rad_s is None or not math.isfinite(sp.yaw_rate_rad_s) else sp.yaw_rate_rad_s
    return OffboardSetpoint(pos, zero_nan(sp.vel_m_s), zero_nan(sp.acc_m_s2), yaw, rate, sp.frame)


def _num(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def _nan_if_bad(x: float) -> float:
    return x if math.isfinite(x) else math.nan

"""Navigator: turns the active flight mode into a position-controller setpoint.

It plays the part of PX4's navigator and flight tasks: takeoff (climb straight
up at MPC_TKO_SPEED), hold (brake, then keep the stopping point), land (descend
at MPC_Z_VEL_MAX_DN, then MPC_LAND_SPEED below MPC_LAND_ALT2), return to launch
(climb to RTL_RETURN_ALT, fly home, land) and missions (items in the local
frame, accepted within their radius). Heights are above home; positions NED.

Auto modes do not hand the raw target to the position controller: a
:class:`Carrot` runs ahead of the vehicle from its position toward the target
with trapezoidal speed (speed and acceleration limits from the params) and the
controller tracks the carrot's position plus its velocity and acceleration as
feed-forward, so
takeoffs, waypoints and returns arrive crisply instead of creeping in on a
P-law tail (PX4's flight tasks do the same with jerk-limited trajectories).

The per-mode methods return a :class:`Guidance`: the setpoint plus the speed
limits that apply to it, and set ``event`` when a manoeuvre completes
("takeoff_done", "mission_rtl", "mission_land") so the commander can switch modes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from flightsim.api import NavCommand, NavItem, State
from flightsim.control import Setpoint
from flightsim.control.rotation import Vec3
from flightsim.params import Params

NAN = math.nan


@dataclass(frozen=True, slots=True)
class Guidance:
    setpoint: Setpoint
    xy_speed_m_s: float
    up_speed_m_s: float
    dn_speed_m_s: float
    wants_climb: bool  # on the ground: should the motors spool up and leave it?


class RtlPhase(Enum):
    CLIMB = 1
    RETURN = 2
    LAND = 3


class Carrot:
    """A point moving toward a target with limited speed and acceleration (NED, SI).

    Two stages. The raw carrot moves horizontally and vertically (separately):
    each accelerates at most ``acc`` toward the speed ``min(cap, sqrt(2 acc
    distance))``, the fastest speed from which it can still stop on the target,
    and snaps onto the target when the next step would reach it. A critically
    damped second-order filter (natural frequency ``SMOOTHING_RAD_S``) then
    smooths it, so the acceleration it hands the controller is continuous: a
    quad needs time to tilt, and an acceleration step would leave it behind and
    make it overshoot. The filter's impulse response is non-negative, so the
    smoothed point never passes the target either.

    ``pos``, ``vel`` and ``acc`` are the smoothed point: the controller's
    position setpoint and its velocity and acceleration feed-forward.
    """

    SMOOTHING_RAD_S = 4.0

    def __init__(self) -> None:
        self.reset((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    def reset(self, pos: Vec3, vel: Vec3) -> None:
        self._raw_pos, self._raw_vel = pos, vel
        self.pos, self.vel, self.acc = pos, vel, (0.0, 0.0, 0.0)

    def advance(
        self, target: Vec3, xy_cap: float, up_cap: float, dn_cap: float, acc_xy: float, acc_z: float, dt_s: float
    ) -> None:
        rp, rv = self._raw_pos, self._raw_vel
        (x, y), (vx, vy) = _shape((rp[0], rp[1]), (rv[0], rv[1]), (target[0], target[1]), xy_cap, acc_xy, dt_s)
        z_cap = dn_cap if target[2] > rp[2] else up_cap
        (z,), (vz,) = _shape((rp[2],), (rv[2],), (target[2],), z_cap, acc_z, dt_s)
        self._raw_pos, self._raw_vel = (x, y, z), (vx, vy, vz)
        # Smoothing: a'' = w^2 (raw - p) - 2 w v, integrated semi-implicitly (velocity first).
        w = self.SMOOTHING_RAD_S
        r, p, v = self._raw_pos, self.pos, self.vel
        ax, ay, az = (w * w * (r[i] - p[i]) - 2 * w * v[i] for i in range(3))
        vx, vy, vz = v[0] + ax * dt_s, v[1] + ay * dt_s, v[2] + az * dt_s
        self.pos = (p[0] + vx * dt_s, p[1] + vy * dt_s, p[2] + vz * dt_s)
        self.vel, self.acc = (vx, vy, vz), (ax, ay, az)


def _shape(
    pos: tuple[float, ...], vel: tuple[float, ...], target: tuple[float, ...], cap: float, acc: float, dt_s: float
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """One step of the carrot along 1 or 2 axes: returns the new (position, velocity)."""
    d = [t - p for t, p in zip(target, pos, strict=True)]
    dist = math.sqrt(sum(c * c for c in d))
    speed_now = math.sqrt(sum(c * c for c in vel))
    if dist <= max(speed_now * dt_s, 1e-6):
        return target, tuple(0.0 for _ in pos)
    want = min(cap, math.sqrt(2 * acc * dist))
    desired = [c / dist * want for c in d]
    dv = [w - v for w, v in zip(desired, vel, strict=True)]
    dv_norm = math.sqrt(sum(c * c for c in dv))
    limit = acc * dt_s
    if dv_norm > limit:
        dv = [c * limit / dv_norm for c in dv]
    new_vel = tuple(v + c for v, c in zip(vel, dv, strict=True))
    if math.sqrt(sum(c * c for c in new_vel)) * dt_s >= dist:
        # this step would reach (or pass) the target: a few micrometres away the speed the braking curve
        # allows still covers more than the distance in one step, so snap rather than step past it
        return target, tuple(0.0 for _ in pos)
    return tuple(p + v * dt_s for p, v in zip(pos, new_vel, strict=True)), new_vel


class Navigator:
    def __init__(self, params: Params) -> None:
        self.p = params
        self.hold_pos: Vec3 = (0.0, 0.0, 0.0)
        self.hold_xy_speed: float | None = None  # None: MPC_XY_VEL_MAX; a reposition flies at cruise speed
        self.speed_override_m_s: float | None = None  # MAV_CMD_DO_CHANGE_SPEED: beats MPC_XY_CRUISE and item speeds
        self.yaw: float = 0.0
        self.target: Vec3 = (0.0, 0.0, 0.0)
        self.rtl_phase = RtlPhase.CLIMB
        self.rtl_alt_m = 0.0
        self.mission: list[NavItem] = []
        self.mission_current = 0
        self.mission_finished = False
        self._mission_hold_until: float | None = None
        self._mission_climb_alt: float | None = None
        self.event: str | None = None
        self.carrot = Carrot()
        self.dt_s = 0.02  # the commander sets the control period before each tick

    # -- starting manoeuvres ---------------------------------------------------
    def start_hold(self, est: State) -> None:
        """Brake to the stopping point (constant deceleration MPC_ACC_HOR) and keep it."""
        p, v = est.pos_ned_m, est.vel_ned_m_s
        a = self.p["MPC_ACC_HOR"]
        speed = math.hypot(v[0], v[1])
        k = speed / (2 * a)
        a_z = min(self.p["MPC_ACC_UP_MAX"], self.p["MPC_ACC_DOWN_MAX"])
        self.hold_pos = (p[0] + v[0] * k, p[1] + v[1] * k, p[2] + v[2] * abs(v[2]) / (2 * a_z))
        self.hold_xy_speed = None
        self.yaw = est.euler_rad[2]
        self.carrot.reset(p, v)

    def start_takeoff(self, est: State, altitude_m: float) -> None:
        p = est.pos_ned_m
        self.target = (p[0], p[1], -altitude_m)
        self.yaw = est.euler_rad[2]
        self.carrot.reset(p, est.vel_ned_m_s)

    def start_land(self, est: State) -> None:
        self.target = est.pos_ned_m
        self.yaw = est.euler_rad[2]

    def start_rtl(self, est: State) -> None:
        p = est.pos_ned_m
        self.yaw = est.euler_rad[2]
        self.rtl_alt_m = max(self.p["RTL_RETURN_ALT"], -p[2])
        self.target = (p[0], p[1], -self.rtl_alt_m)
        self.rtl_phase = RtlPhase.LAND if math.hypot(p[0], p[1]) < self.p["NAV_ACC_RAD"] else RtlPhase.CLIMB
        self.carrot.reset(p, est.vel_ned_m_s)

    def start_mission(self, est: State, landed: bool) -> None:
        self.mission_finished = False
        self._mission_hold_until = None
        self.yaw = est.euler_rad[2]
        self.hold_pos = est.pos_ned_m
        self._mission_climb_alt = None
        self.carrot.reset(est.pos_ned_m, est.vel_ned_m_s)
        if landed and self.mission_current < len(self.mission):
            item = self.mission[self.mission_current]
            alt = max(self.p["MIS_TAKEOFF_ALT"], -item.pos_ned_m[2])
            self._mission_climb_alt = alt
            self.target = (est.pos_ned_m[0], est.pos_ned_m[1], -alt)

    def jump_to(self, seq: int) -> None:
        """Make item ``seq`` the current one (a new upload starts at 0)."""
        self.mission_current = seq
        self.mission_finished = False
        self._mission_hold_until = None

    @property
    def mission_climbing(self) -> bool:
        """Still in the vertical climb that starts a mission from the ground."""
        return self._mission_climb_alt is not None

    # -- per control tick -------------------------------------------------------
    def hold(self) -> Guidance:
        return self._go(self.hold_pos, xy=self.hold_xy_speed)

    def start_reposition(self, est: State, pos: Vec3, yaw: float | None) -> None:
        """Hold somewhere else: fly there at MPC_XY_CRUISE (NaN or infinite axes keep the current value)."""
        cur = est.pos_ned_m
        n, e, d = (p if math.isfinite(p) else c for p, c in zip(pos, cur, strict=True))
        self.hold_pos = (n, e, d)
        if yaw is not None and math.isfinite(yaw):
            self.yaw = yaw
        self.hold_xy_speed = self.cruise_m_s()
        self.carrot.reset(cur, est.vel_ned_m_s)

    def takeoff(self, est: State) -> Guidance:
        if abs(est.pos_ned_m[2] - self.target[2]) < self.p["NAV_MC_ALT_RAD"]:
            self.event = "takeoff_done"
        return self._go(self.target, up=self.p["MPC_TKO_SPEED"])

    def land(self, est: State) -> Guidance:
        alt = -est.pos_ned_m[2]
        speed = self.p["MPC_Z_VEL_MAX_DN"] if alt > self.p["MPC_LAND_ALT2"] else self.p["MPC_LAND_SPEED"]
        sp = Setpoint(pos_ned_m=(self.target[0], self.target[1], NAN), vel_ned_m_s=(0.0, 0.0, speed), yaw_rad=self.yaw)
        return Guidance(sp, self.p["MPC_XY_CRUISE"], self.p["MPC_Z_VEL_MAX_UP"], speed, False)

    def rtl(self, est: State) -> Guidance:
        p = est.pos_ned_m
        if self.rtl_phase is RtlPhase.CLIMB:
            if p[2] - self.target[2] < self.p["NAV_MC_ALT_RAD"]:
                self.rtl_phase = RtlPhase.RETURN
                self.target = (0.0, 0.0, -self.rtl_alt_m)
            return self._go(self.target)
        if self.rtl_phase is RtlPhase.RETURN:
            self._face(p, self.target)
            if math.hypot(p[0] - self.target[0], p[1] - self.target[1]) < self.p["NAV_ACC_RAD"]:
                self.rtl_phase = RtlPhase.LAND
                self.target = (0.0, 0.0, p[2])
            return self._go(self.target, xy=self.p["MPC_XY_CRUISE"])
        return self.land(est)

    def mission_step(self, est: State, t_s: float) -> Guidance:
        """Fly the current item; advance when it is reached (and its hold time is over)."""
        if self._mission_climb_alt is not None:
            if abs(est.pos_ned_m[2] - self.target[2]) < self.p["NAV_MC_ALT_RAD"]:
                self._mission_climb_alt = None
                if self.mission[self.mission_current].command == NavCommand.TAKEOFF:
                    self._advance(est)
            return self._go(self.target, up=self.p["MPC_TKO_SPEED"])
        if self.mission_finished or self.mission_current >= len(self.mission):
            self.mission_finished = True
            return self._go(self.hold_pos)
        item = self.mission[self.mission_current]
        if item.yaw_rad is not None:
            self.yaw = item.yaw_rad
        if item.command == NavCommand.RETURN_TO_LAUNCH:
            self.event = "mission_rtl"
            return self._go(self.hold_pos)
        if item.command == NavCommand.TAKEOFF:
            p = est.pos_ned_m
            self.target = (p[0], p[1], item.pos_ned_m[2])
            self._mission_climb_alt = -item.pos_ned_m[2]
            return self._go(self.target, up=self.p["MPC_TKO_SPEED"])
        goal = item.pos_ned_m
        if item.command == NavCommand.LAND:
            goal = (goal[0], goal[1], est.pos_ned_m[2])
        radius = item.acceptance_radius_m if item.acceptance_radius_m > 0 else self.p["NAV_ACC_RAD"]
        p = est.pos_ned_m
        if item.yaw_rad is None:
            self._face(p, goal)
        reached = math.hypot(p[0] - goal[0], p[1] - goal[1]) < radius and abs(p[2] - goal[2]) < self.p["NAV_MC_ALT_RAD"]
        if reached:
            if item.command == NavCommand.LAND:
                self.target = goal
                self.event = "mission_land"
                return self.land(est)
            if item.command == NavCommand.LOITER_UNLIM:
                return self._go(goal)
            if self._mission_hold_until is None:
                self._mission_hold_until = t_s + item.hold_s
            if t_s >= self._mission_hold_until:
                self._advance(est, goal)
        return self._go(goal, xy=self.cruise_m_s(item.speed_m_s))

    def cruise_m_s(self, item_speed_m_s: float | None = None) -> float:
        """Horizontal speed on auto legs: a DO_CHANGE_SPEED command, else the item's, else MPC_XY_CRUISE."""
        speed = self.speed_override_m_s or item_speed_m_s or self.p["MPC_XY_CRUISE"]
        return min(speed, self.p["MPC_XY_VEL_MAX"])

    def _face(self, pos: Vec3, goal: Vec3) -> None:
        """Heading on an auto leg, by MPC_YAW_MODE as PX4: 0/3/4 toward the goal, 1 toward home, 2 away.

        Kept unchanged within NAV_ACC_RAD of the goal, so the vehicle does not spin on arrival.
        """
        dn, de = goal[0] - pos[0], goal[1] - pos[1]
        if math.hypot(dn, de) < self.p["NAV_ACC_RAD"]:
            return
        mode = int(self.p["MPC_YAW_MODE"])
        if mode == 1:
            dn, de = -pos[0], -pos[1]
        elif mode == 2:
            dn, de = pos[0], pos[1]
        if math.hypot(dn, de) > 1e-6:
            self.yaw = math.atan2(de, dn)

    def _advance(self, est: State, reached: Vec3 | None = None) -> None:
        self._mission_hold_until = None
        self.hold_pos = reached if reached is not None else est.pos_ned_m
        self.mission_current += 1
        if self.mission_current >= len(self.mission):
            self.mission_current = max(0, len(self.mission) - 1)
            self.mission_finished = True

    def _go(self, pos: Vec3, xy: float | None = None, up: float | None = None) -> Guidance:
        """Fly toward ``pos`` behind the carrot, within the given (or default) speed limits."""
        p = self.p
        xy_cap = xy if xy is not None else p["MPC_XY_VEL_MAX"]
        up_cap = up if up is not None else p["MPC_Z_VEL_MAX_UP"]
        dn_cap = p["MPC_Z_VEL_MAX_DN"]
        acc_z = min(p["MPC_ACC_UP_MAX"], p["MPC_ACC_DOWN_MAX"])
        self.carrot.advance(pos, xy_cap, up_cap, dn_cap, p["MPC_ACC_HOR"], acc_z, self.dt_s)
        c = self.carrot
        sp = Setpoint(pos_ned_m=c.pos, vel_ned_m_s=c.vel, acc_ned_m_s2=c.acc, yaw_rad=self.yaw)
        return Guidance(sp, xy_cap, up_cap, dn_cap, wants_climb=pos[2] < -0.3)

    def rest(self, est: State) -> None:
        """On the ground with motors idle: keep the carrot under the vehicle."""
        self.carrot.reset(est.pos_ned_m, (0.0, 0.0, 0.0))

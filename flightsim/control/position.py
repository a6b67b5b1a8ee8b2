"""Position and velocity control: a setpoint in NED -> attitude setpoint + thrust.

The cascade follows PX4's mc_pos_control:

1. position error -> velocity setpoint (P, with a square-root braking law so a
   large step arrives without overshoot, then the speed limits of the params),
2. velocity error -> acceleration setpoint (PID, D on the measured velocity),
3. acceleration -> thrust vector ``m (a - g)``, tilt-limited, -> body z axis,
   which with the yaw setpoint gives the attitude setpoint; the collective
   thrust is the thrust vector projected on the current body z axis.

Any group of the setpoint may be ``None``: with no position the velocity is
the target, with neither the acceleration alone is flown. Units SI, NED frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from flightsim.control.rotation import Quat, Vec3, quat_from_body_z_and_yaw, rotate, wrap_pi

GRAVITY_M_S2 = 9.80665
INTEGRATE_BELOW_M_S = 0.5


@dataclass(frozen=True, slots=True)
class Setpoint:
    """What the commander asks the position controller to fly (NED, SI)."""

    pos_ned_m: Vec3 | None = None
    vel_ned_m_s: Vec3 | None = None  # feed-forward when a position is given
    acc_ned_m_s2: Vec3 | None = None
    yaw_rad: float | None = None
    yaw_rate_rad_s: float | None = None


@dataclass(frozen=True, slots=True)
class Limits:
    """Speed and tilt limits, from the PX4 params of the same meaning."""

    xy_vel_max_m_s: float = 12.0  # MPC_XY_VEL_MAX
    z_vel_max_up_m_s: float = 3.0  # MPC_Z_VEL_MAX_UP
    z_vel_max_dn_m_s: float = 1.5  # MPC_Z_VEL_MAX_DN
    acc_hor_m_s2: float = 3.0  # MPC_ACC_HOR: used by the braking law
    tilt_max_rad: float = math.radians(35.0)  # MPC_TILTMAX_AIR


@dataclass(frozen=True, slots=True)
class PositionGains:
    xy_p: float = 1.2  # MPC_XY_P, 1/s
    z_p: float = 1.0  # MPC_Z_P
    xy_vel_p: float = 4.0  # MPC_XY_VEL_P_ACC, (m/s^2)/(m/s)
    xy_vel_i: float = 0.4  # MPC_XY_VEL_I_ACC
    xy_vel_d: float = 0.2  # MPC_XY_VEL_D_ACC
    z_vel_p: float = 4.0  # MPC_Z_VEL_P_ACC
    z_vel_i: float = 2.0  # MPC_Z_VEL_I_ACC
    z_vel_d: float = 0.0
    i_limit_m_s2: float = 3.0


@dataclass(frozen=True, slots=True)
class AttitudeTarget:
    quat: Quat
    thrust_n: float
    yaw_rate_ff_rad_s: float


class PositionController:
    def __init__(self, mass_kg: float, gains: PositionGains | None = None, limits: Limits | None = None) -> None:
        self.mass_kg = mass_kg
        self.gains = gains or PositionGains()
        self.limits = limits or Limits()
        self._integral = [0.0, 0.0, 0.0]
        self._prev_vel: Vec3 | None = None
        self.yaw_sp: float | None = None
        self.vel_sp: Vec3 = (0.0, 0.0, 0.0)

    def reset(self, hover_integral_z: float = 0.0) -> None:
        self._integral = [0.0, 0.0, hover_integral_z]
        self._prev_vel = None
        self.yaw_sp = None

    def _velocity_setpoint(self, sp: Setpoint, pos: Vec3) -> Vec3:
        """Position error -> velocity setpoint; a NaN position axis means "velocity only" there."""
        g, lim = self.gains, self.limits
        ff = sp.vel_ned_m_s or (0.0, 0.0, 0.0)
        vx, vy, vz = ff
        p = sp.pos_ned_m
        if p is not None and not (math.isnan(p[0]) or math.isnan(p[1])):
            ex, ey = p[0] - pos[0], p[1] - pos[1]
            dist_xy = math.hypot(ex, ey)
            # P near the target, square-root braking law (constant deceleration) farther out.
            speed_xy = min(g.xy_p * dist_xy, math.sqrt(2 * lim.acc_hor_m_s2 * dist_xy))
            scale = speed_xy / dist_xy if dist_xy > 1e-9 else 0.0
            vx, vy = ex * scale + ff[0], ey * scale + ff[1]
        if p is not None and not math.isnan(p[2]):
            vz = g.z_p * (p[2] - pos[2]) + ff[2]
        speed = math.hypot(vx, vy)
        if speed > lim.xy_vel_max_m_s:
            vx, vy = vx * lim.xy_vel_max_m_s / speed, vy * lim.xy_vel_max_m_s / speed
        vz = max(-lim.z_vel_max_up_m_s, min(lim.z_vel_max_dn_m_s, vz))
        return vx, vy, vz

    def update(self, sp: Setpoint, pos: Vec3, vel: Vec3, yaw: float, q: Quat, dt_s: float) -> AttitudeTarget:
        g, lim = self.gains, self.limits
        acc_ff = sp.acc_ned_m_s2 or (0.0, 0.0, 0.0)
        if sp.pos_ned_m is None and sp.vel_ned_m_s is None:
            acc = list(acc_ff)
            self._integral = [0.0, 0.0, self._integral[2]]
            self.vel_sp = vel
        else:
            vsp = self._velocity_setpoint(sp, pos)
            self.vel_sp = vsp
            prev = self._prev_vel or vel
            acc = [0.0, 0.0, 0.0]
            for i in range(3):
                kp, ki, kd = (g.xy_vel_p, g.xy_vel_i, g.xy_vel_d) if i < 2 else (g.z_vel_p, g.z_vel_i, g.z_vel_d)
                err = vsp[i] - vel[i]
                # Integrate only near the setpoint: during a manoeuvre the error is
                # transient, and winding it up would cost an overshoot afterwards.
                if abs(err) < INTEGRATE_BELOW_M_S:
                    i_max = g.i_limit_m_s2
                    self._integral[i] = max(-i_max, min(i_max, self._integral[i] + ki * err * dt_s))
                acc[i] = kp * err + self._integral[i] - kd * (vel[i] - prev[i]) / dt_s + acc_ff[i]
        self._prev_vel = vel
        # Thrust vector (N, NED) that produces the acceleration against gravity.
        fx, fy = self.mass_kg * acc[0], self.mass_kg * acc[1]
        fz = self.mass_kg * (acc[2] - GRAVITY_M_S2)
        fz = min(fz, -0.1 * self.mass_kg * GRAVITY_M_S2)  # never ask to be pulled down harder than gravity
        f_hor = math.hypot(fx, fy)
        f_hor_max = -fz * math.tan(lim.tilt_max_rad)
        if f_hor > f_hor_max:
            fx, fy = fx * f_hor_max / f_hor, fy * f_hor_max / f_hor
        norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        body_z = (-fx / norm, -fy / norm, -fz / norm)
        if sp.yaw_rad is not None:
            self.yaw_sp = sp.yaw_rad
        elif self.yaw_sp is None:
            self.yaw_sp = yaw
        yaw_rate_ff = 0.0
        if sp.yaw_rad is None and sp.yaw_rate_rad_s is not None:
            yaw_rate_ff = sp.yaw_rate_rad_s
            # Track the integrated heading but never let it run away from the real one.
            self.yaw_sp = yaw + max(-0.3, min(0.3, wrap_pi(self.yaw_sp + yaw_rate_ff * dt_s - yaw)))
        q_sp = quat_from_body_z_and_yaw(body_z, self.yaw_sp)
        cur_z = rotate(q, (0.0, 0.0, 1.0))
        thrust = max(0.0, -(fx * cur_z[0] + fy * cur_z[1] + fz * cur_z[2]))
        return AttitudeTarget(q_sp, thrust, yaw_rate_ff)

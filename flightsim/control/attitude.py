"""Attitude P controller: attitude setpoint -> body-rate setpoint (rad/s).

The error is the rotation from the current attitude to the setpoint, expressed
in the body frame (``q_err = q^-1 q_sp``); its vector part times two is the
small-angle rotation vector. Yaw gets a lower gain than roll and pitch, as in
PX4, because yaw authority of a quad is weak and tilt matters more.
"""

from __future__ import annotations

from dataclasses import dataclass

from flightsim.control.rotation import Quat, Vec3, quat_conj, quat_mul


@dataclass(frozen=True, slots=True)
class AttitudeGains:
    kp: Vec3 = (6.0, 6.0, 2.8)  # (rad/s) per rad, PX4's MC_ROLL_P/MC_PITCH_P/MC_YAW_P
    rate_max: Vec3 = (3.8, 3.8, 2.0)  # rad/s, about PX4's 220/220/200 deg/s and a gentler yaw


class AttitudeController:
    def __init__(self, gains: AttitudeGains | None = None) -> None:
        self.gains = gains or AttitudeGains()

    def update(self, q: Quat, q_sp: Quat, yaw_rate_ff: float = 0.0) -> Vec3:
        ew, ex, ey, ez = quat_mul(quat_conj(q), q_sp)
        if ew < 0:  # take the short way round
            ex, ey, ez = -ex, -ey, -ez
        g = self.gains
        out = (2 * ex * g.kp[0], 2 * ey * g.kp[1], 2 * ez * g.kp[2] + yaw_rate_ff)
        return (
            max(-g.rate_max[0], min(g.rate_max[0], out[0])),
            max(-g.rate_max[1], min(g.rate_max[1], out[1])),
            max(-g.rate_max[2], min(g.rate_max[2], out[2])),
        )

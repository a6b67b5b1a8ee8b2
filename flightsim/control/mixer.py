"""X-quad mixer: collective thrust and body torques -> four motor commands.

Motor order is JSBSim's F450 engine order: front-right, aft-left, front-left,
aft-right. Body frame is FRD (x forward, y right, z down). A motor at
``(x_i, y_i)`` pushing up with force ``f_i`` makes roll torque ``-y_i f_i`` and
pitch torque ``x_i f_i``; its drag torque is ``kappa s_i f_i`` about z, with
``s_i`` = +1 for front-right/aft-left and -1 for the others (measured on the
JSBSim model: raising FR+AL yaws the nose right).

Motor force as a function of command ``c`` (0..1) was fitted on the JSBSim
model in static thrust: ``f = a c^2 + b c``; the mixer inverts it so the
controllers can reason in newtons.

Saturation follows PX4's priorities: roll/pitch first (the collective is shifted
and, if needed, the roll/pitch demand scaled), yaw only with the headroom left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from flightsim.control.rotation import Vec3

MOTOR_NAMES = ("FR", "AL", "FL", "AR")
ARM_M = 0.1651  # JSBSim F450 motor offset along x and y
MOTOR_X = (ARM_M, -ARM_M, ARM_M, -ARM_M)
MOTOR_Y = (ARM_M, -ARM_M, -ARM_M, ARM_M)
MOTOR_SPIN = (1.0, 1.0, -1.0, -1.0)


@dataclass(frozen=True, slots=True)
class MotorModel:
    """Static thrust of one F450 motor: ``f_N = a c^2 + b c`` for command c in 0..1."""

    a_n: float = 17.78
    b_n: float = 0.90
    yaw_moment_m: float = 0.021  # drag torque per newton of thrust (kappa)
    idle_cmd: float = 0.08  # armed, flying minimum (keeps props spinning, like PX4's idle)

    def force_n(self, cmd: float) -> float:
        return self.a_n * cmd * cmd + self.b_n * cmd

    def cmd_for(self, force_n: float) -> float:
        if force_n <= 0.0:
            return 0.0
        a, b = self.a_n, self.b_n
        return (-b + math.sqrt(b * b + 4 * a * force_n)) / (2 * a)

    @property
    def max_force_n(self) -> float:
        return self.force_n(1.0)


class XQuadMixer:
    """Allocates thrust (N) and torques (N m, body FRD) to motor commands 0..1."""

    def __init__(self, motor: MotorModel | None = None) -> None:
        self.motor = motor or MotorModel()
        self.f_min = self.motor.force_n(self.motor.idle_cmd)
        self.f_max = self.motor.max_force_n
        self.saturated = False
        self._k_rp = 1.0 / (4 * ARM_M)

    def mix(self, thrust_n: float, torque_nm: Vec3) -> tuple[float, float, float, float]:
        tx, ty, tz = torque_nm
        # Roll/pitch share of each motor (FR, AL, FL, AR), from f_i = -y_i tx/(4L^2) + x_i ty/(4L^2).
        rx = tx * self._k_rp
        ry = ty * self._k_rp
        rp = (-rx + ry, rx - ry, rx + ry, -rx - ry)
        f_min, f_max = self.f_min, self.f_max
        saturated = False
        spread = max(rp) - min(rp)
        if spread > f_max - f_min:
            scale = (f_max - f_min) / spread
            rp = (rp[0] * scale, rp[1] * scale, rp[2] * scale, rp[3] * scale)
            saturated = True
        base = thrust_n / 4
        lo, hi = base + min(rp), base + max(rp)
        if lo < f_min:
            base += f_min - lo
            saturated = True
        elif hi > f_max:
            base -= hi - f_max
            saturated = True
        f0, f1, f2, f3 = base + rp[0], base + rp[1], base + rp[2], base + rp[3]
        # Yaw: FR and AL spin one way (+), FL and AR the other (-). Only the headroom left is used.
        yaw = tz / (4 * self.motor.yaw_moment_m)
        if yaw >= 0:
            room = min(f_max - f0, f_max - f1, f2 - f_min, f3 - f_min)
        else:
            room = min(f0 - f_min, f1 - f_min, f_max - f2, f_max - f3)
        if abs(yaw) > room:
            yaw = math.copysign(max(room, 0.0), yaw)
            saturated = True
        self.saturated = saturated
        cmd = self.motor.cmd_for
        return cmd(f0 + yaw), cmd(f1 + yaw), cmd(f2 - yaw), cmd(f3 - yaw)

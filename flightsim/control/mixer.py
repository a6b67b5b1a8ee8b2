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

    def mix(self, thrust_n: float, torque_nm: Vec3) -> tuple[float, float, float, float]:
        tx, ty, tz = torque_nm
        k = 1.0 / (4 * ARM_M * ARM_M)
        rp = [(-MOTOR_Y[i] * tx + MOTOR_X[i] * ty) * k for i in range(4)]
        span = self.f_max - self.f_min
        spread = max(rp) - min(rp)
        self.saturated = False
        if spread > span:
            scale = span / spread
            rp = [v * scale for v in rp]
            self.saturated = True
        base = thrust_n / 4
        lo, hi = base + min(rp), base + max(rp)
        if lo < self.f_min:
            base += self.f_min - lo
            self.saturated = True
        elif hi > self.f_max:
            base -= hi - self.f_max
            self.saturated = True
        forces = [base + v for v in rp]
        yaw_each = tz / (4 * self.motor.yaw_moment_m)
        # Largest yaw share every motor can still take without leaving its range.
        room = math.inf
        for i in range(4):
            push = MOTOR_SPIN[i] * (1.0 if yaw_each >= 0 else -1.0)
            room = min(room, self.f_max - forces[i] if push > 0 else forces[i] - self.f_min)
        if abs(yaw_each) > room:
            yaw_each = math.copysign(max(room, 0.0), yaw_each)
            self.saturated = True
        cmd = self.motor.cmd_for
        return (
            cmd(forces[0] + MOTOR_SPIN[0] * yaw_each),
            cmd(forces[1] + MOTOR_SPIN[1] * yaw_each),
            cmd(forces[2] + MOTOR_SPIN[2] * yaw_each),
            cmd(forces[3] + MOTOR_SPIN[3] * yaw_each),
        )

"""Body-rate PID: rate setpoint (rad/s) -> torque (N m), like PX4's mc_rate_control.

The loop works in angular acceleration (rad/s^2) and multiplies by the inertia,
so the gains do not depend on the airframe's size. D acts on the measured rate
(not the error) so a setpoint step gives no derivative kick. The integrator
is frozen while the mixer saturates (anti-windup) and reset on the ground.
"""

from __future__ import annotations

from dataclasses import dataclass

from flightsim.control.rotation import Vec3


@dataclass(frozen=True, slots=True)
class RateGains:
    kp: Vec3 = (18.0, 18.0, 6.0)  # (rad/s^2) per (rad/s)
    ki: Vec3 = (6.0, 6.0, 2.0)
    kd: Vec3 = (0.35, 0.35, 0.0)  # (rad/s^2) per (rad/s^2)
    i_limit: Vec3 = (3.0, 3.0, 2.0)  # rad/s^2


class RateController:
    def __init__(self, inertia_kgm2: Vec3, gains: RateGains | None = None) -> None:
        self.inertia = inertia_kgm2
        self.gains = gains or RateGains()
        self._integral = [0.0, 0.0, 0.0]
        self._prev_rates: Vec3 | None = None

    def reset(self) -> None:
        self._integral = [0.0, 0.0, 0.0]
        self._prev_rates = None

    def update(self, rate_sp: Vec3, rates: Vec3, dt_s: float, saturated: bool) -> Vec3:
        g = self.gains
        prev = self._prev_rates or rates
        self._prev_rates = rates
        integral = self._integral
        out = []
        for i in (0, 1, 2):
            err = rate_sp[i] - rates[i]
            if not saturated:
                lim = g.i_limit[i]
                integral[i] = max(-lim, min(lim, integral[i] + g.ki[i] * err * dt_s))
            alpha = g.kp[i] * err + integral[i] - g.kd[i] * (rates[i] - prev[i]) / dt_s
            out.append(alpha * self.inertia[i])
        return out[0], out[1], out[2]

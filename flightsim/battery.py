"""A simple LiPo pack: drains with motor load, voltage sags as it empties.

Current (A) = ``IDLE_A`` + ``LOAD_A`` x (mean motor command)^1.5, which gives
about 8 A in an F450 hover; remaining = 1 - used charge / capacity; voltage per
cell falls linearly from 4.2 V (full) to 3.5 V (empty), minus an internal
resistance drop. Enough for BATTERY_STATUS and a low-battery arming check.
"""

from __future__ import annotations

IDLE_A = 0.4
LOAD_A = 30.0
CELL_FULL_V = 4.2
CELL_EMPTY_V = 3.5
PACK_RESISTANCE_OHM = 0.02


class Battery:
    def __init__(self, cells: int = 4, capacity_mah: float = 5000.0) -> None:
        self.cells = cells
        self.capacity_mah = capacity_mah
        self.used_mah = 0.0
        self.current_a = 0.0

    def update(self, mean_motor_cmd: float, dt_s: float) -> None:
        self.current_a = IDLE_A + LOAD_A * max(0.0, mean_motor_cmd) ** 1.5
        self.used_mah += self.current_a * dt_s / 3.6

    @property
    def remaining(self) -> float:
        return max(0.0, 1.0 - self.used_mah / self.capacity_mah)

    @property
    def voltage_v(self) -> float:
        cell = CELL_EMPTY_V + (CELL_FULL_V - CELL_EMPTY_V) * self.remaining
        return self.cells * cell - PACK_RESISTANCE_OHM * self.current_a

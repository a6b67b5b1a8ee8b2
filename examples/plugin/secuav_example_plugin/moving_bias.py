"""``moving_bias``: add an offset only while the vehicle moves (a "bias only while moving" attack).

An attacker on the link reads the vehicle's own LOCAL_POSITION_NED (``needs_position``)
and lies only while the vehicle is faster than ``min_speed_mps``: a filter that
trusts its motion model most while it manoeuvres is hit exactly then, and a
hovering vehicle (where a test bench usually looks) sees clean readings.

The speed is the distance the vehicle's position moved over the last ``window_s``
seconds (0.5 s), per vehicle; until that much history has been read it is unknown
and nothing is added. ``stateful``: the primitive watches positions outside its
window too, so it knows the speed the moment the window opens.
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar, Literal

from pydantic import Field

from attack_profiles.primitives.base import Context, Primitive, Sample, Vec3
from attack_profiles.rule import Finite, RuleBase


class MovingBiasRule(RuleBase):
    """``value + offset`` while the vehicle's speed is at least ``min_speed_mps``."""

    kind: Literal["moving_bias"] = "moving_bias"
    offset: Finite = Field(description="added to the value, in the field's physical unit (metres for ranges)")
    min_speed_mps: float = Field(0.3, gt=0.0, allow_inf_nan=False, description="speed above which the offset acts")

    needs_position: ClassVar[bool] = True


class MovingBias(Primitive):
    kind = "moving_bias"
    rule_model = MovingBiasRule
    stateful = True

    def __init__(self, rule: MovingBiasRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.offset = rule.offset
        self.min_speed_mps = rule.min_speed_mps
        self.window_s = 0.5
        self._seen: dict[int, deque[tuple[float, Vec3]]] = {}  # sysid -> (time, position) over the last window

    def speed_mps(self, s: Sample) -> float | None:
        """The vehicle's speed over the last ``window_s`` as the attacker reads it; None until known."""
        pos = s.position_ned_m
        if pos is None:
            return None
        seen = self._seen.setdefault(s.key[0], deque())
        if not seen or s.t_s > seen[-1][0]:
            seen.append((s.t_s, pos))
        while len(seen) > 1 and seen[1][0] <= s.t_s - self.window_s:  # keep one sample at least window_s old
            seen.popleft()
        t0, p0 = seen[0]
        if s.t_s - t0 < self.window_s - 1e-9:
            return None
        return math.dist(pos, p0) / (s.t_s - t0)

    def apply(self, s: Sample, tau_s: float | None) -> None:
        speed = self.speed_mps(s)
        if tau_s is not None and speed is not None and speed >= self.min_speed_mps:
            s.value += self.offset

"""``moving_bias``: add an offset only while the vehicle moves (a "bias only while moving" attack).

An attacker on the link reads the vehicle's own LOCAL_POSITION_NED (``needs_position``)
and lies only while the vehicle is faster than ``min_speed_mps``: a filter that
trusts its motion model most while it manoeuvres is hit exactly then, and a
hovering vehicle (where a test bench usually looks) sees clean readings.

The speed is the distance between the last two distinct positions read, over the
time between them, per vehicle; until two positions have been read it is unknown
and nothing is added. ``stateful``: the primitive watches positions outside its
window too, so it knows the speed the moment the window opens.
"""

from __future__ import annotations

import math
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
        self._track: dict[int, tuple[float, Vec3, float]] = {}  # sysid -> (time, position, speed) at the last move

    def speed_mps(self, s: Sample) -> float | None:
        pos, sysid = s.position_ned_m, s.key[0]
        last = self._track.get(sysid)
        if pos is None:
            return None if last is None else last[2]
        if last is None:
            self._track[sysid] = (s.t_s, pos, math.nan)
            return None
        t0, p0, speed = last
        if pos != p0 and s.t_s > t0:
            speed = math.dist(pos, p0) / (s.t_s - t0)
            self._track[sysid] = (s.t_s, pos, speed)
        return None if math.isnan(speed) else speed

    def apply(self, s: Sample, tau_s: float | None) -> None:
        speed = self.speed_mps(s)
        if tau_s is not None and speed is not None and speed >= self.min_speed_mps:
            s.value += self.offset

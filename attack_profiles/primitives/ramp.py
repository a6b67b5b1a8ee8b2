"""ramp: an offset that grows linearly from the window's start (seed Fig. 5.3, "drift")."""

from __future__ import annotations

from typing import Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase


class RampRule(RuleBase):
    """``value + offset + rate_per_s * tau``; units of the field per second."""

    kind: Literal["ramp"] = "ramp"
    rate_per_s: Finite
    offset: Finite = 0.0


class Ramp(Primitive):
    kind = "ramp"
    rule_model = RampRule

    def __init__(self, rule: RampRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.rate = rule.rate_per_s
        self.offset = rule.offset

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value += self.offset + self.rate * tau_s  # type: ignore[operator]

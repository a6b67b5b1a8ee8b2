"""scale: multiply by a factor (PX4 "wrong": a plausible but wrong reading)."""

from __future__ import annotations

from typing import Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase


class ScaleRule(RuleBase):
    """``value * factor``."""

    kind: Literal["scale"] = "scale"
    factor: Finite


class Scale(Primitive):
    kind = "scale"
    rule_model = ScaleRule
    pure = True

    def __init__(self, rule: ScaleRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.factor = rule.factor

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value *= self.factor

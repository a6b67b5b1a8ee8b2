"""set: replace the value with a constant (PX4 "off" for a range sensor reads as 0)."""

from __future__ import annotations

from typing import ClassVar, Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase


class SetRule(RuleBase):
    """``value := value`` parameter, in the field's physical unit."""

    kind: Literal["set"] = "set"
    value: Finite

    clamps_to_limits: ClassVar[bool] = False  # the profile's value, also outside [min, max] ("reads 0")


class Set(Primitive):
    kind = "set"
    rule_model = SetRule

    def __init__(self, rule: SetRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.value = rule.value

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value = self.value

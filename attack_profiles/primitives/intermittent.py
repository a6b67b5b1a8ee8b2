"""intermittent: the target works for ``on_s``, then is silent for ``off_s``, and so on (PX4 "intermittent")."""

from __future__ import annotations

from typing import ClassVar, Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Positive, RuleBase


class IntermittentRule(RuleBase):
    """From the window's start: frames pass for ``on_s``, are dropped for ``off_s``, repeat."""

    kind: Literal["intermittent"] = "intermittent"
    frame_level: ClassVar[bool] = True
    on_s: Positive
    off_s: Positive


class Intermittent(Primitive):
    kind = "intermittent"
    rule_model = IntermittentRule

    def __init__(self, rule: IntermittentRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.on_s = rule.on_s
        self.cycle_s = rule.on_s + rule.off_s

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if tau_s % self.cycle_s >= self.on_s:  # type: ignore[operator]
            s.drop = True

"""drop: the frame never arrives (PX4 "off"; ArduPilot "GPS disable"), always or with a probability."""

from __future__ import annotations

from typing import ClassVar, Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Probability, RuleBase


class DropRule(RuleBase):
    """Drop each matching frame with ``probability`` (1: all of them). Offline, a dropped sample is NaN."""

    kind: Literal["drop"] = "drop"
    frame_level: ClassVar[bool] = True
    probability: Probability = 1.0


class Drop(Primitive):
    kind = "drop"
    rule_model = DropRule

    def __init__(self, rule: DropRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.probability = rule.probability
        self.rng = ctx.rng

    def apply(self, s: Sample, tau_s: float | None) -> None:
        # Draw only when it matters, so "drop all" consumes no randomness.
        if self.probability >= 1.0 or self.rng.random() < self.probability:
            s.drop = True

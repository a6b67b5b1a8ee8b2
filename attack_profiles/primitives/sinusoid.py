"""sinusoid: an oscillating offset (seed Fig. 5.3's oscillating attack)."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase


class SinusoidRule(RuleBase):
    """``value + amplitude * sin(2 pi tau / period_s + phase_deg)``."""

    kind: Literal["sinusoid"] = "sinusoid"
    amplitude: Finite
    period_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    phase_deg: Finite = 0.0


class Sinusoid(Primitive):
    kind = "sinusoid"
    rule_model = SinusoidRule

    def __init__(self, rule: SinusoidRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.amplitude = rule.amplitude
        self.omega = 2.0 * math.pi / rule.period_s
        self.phase = math.radians(rule.phase_deg)

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value += self.amplitude * math.sin(self.omega * tau_s + self.phase)  # type: ignore[operator]

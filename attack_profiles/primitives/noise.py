"""noise: zero-mean random noise from the rule's own seeded generator (ArduPilot "rangefinder noise")."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import RuleBase


class NoiseRule(RuleBase):
    """Add noise of standard deviation ``std``: gaussian, or uniform on ``[-std*sqrt(3), std*sqrt(3)]``."""

    kind: Literal["noise"] = "noise"
    std: Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
    distribution: Literal["gaussian", "uniform"] = "gaussian"


class Noise(Primitive):
    kind = "noise"
    rule_model = NoiseRule

    def __init__(self, rule: NoiseRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.std = rule.std
        self.half_width = rule.std * math.sqrt(3.0)  # same variance as the gaussian
        self.gaussian = rule.distribution == "gaussian"
        self.rng = ctx.rng

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if self.gaussian:
            s.value += self.rng.gauss(0.0, self.std)
        else:
            s.value += self.rng.uniform(-self.half_width, self.half_width)

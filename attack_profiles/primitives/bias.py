"""bias: add a constant offset (seed "type A": constant-offset injection).

``offset_sigmas`` instead of ``offset`` sizes the offset in units of each
sensor's own noise standard deviation in the scenario (a stealthy attack is
"k sigma", whatever the sensor), so it needs the scenario.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import model_validator

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase
from secuav_common.loading import InputError


class BiasRule(RuleBase):
    """``value + offset``; ``offset`` in the field's physical unit (``offset_m`` is accepted too)."""

    kind: Literal["bias"] = "bias"
    offset: Finite | None = None
    offset_sigmas: Finite | None = None

    @model_validator(mode="after")
    def _one_size(self) -> BiasRule:
        if (self.offset is None) == (self.offset_sigmas is None):
            raise ValueError("give exactly one of offset (in the field's unit) and offset_sigmas (noise sigmas)")
        return self

    @model_validator(mode="before")
    @classmethod
    def _design_spelling(cls, data: Any) -> Any:
        # Older profiles write ``offset_m``; accept it so both spellings work.
        if isinstance(data, dict) and "offset_m" in data and "offset" not in data:
            data = {("offset" if k == "offset_m" else k): v for k, v in data.items()}
        return data


class Bias(Primitive):
    kind = "bias"
    rule_model = BiasRule
    pure = True  # offset_sigmas: the sigma is the sensor's, and the sensor id is in the key

    def __init__(self, rule: BiasRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.offset = rule.offset
        self.sigmas = rule.offset_sigmas
        if self.sigmas is not None and not ctx.noise_std_m:
            raise InputError("profile", f"rules[{ctx.rule_index}].offset_sigmas", self.sigmas,
                             "needs a scenario for the sensors' noise")  # fmt: skip

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if self.offset is not None:
            s.value += self.offset
        else:
            s.value += self.sigmas * self.ctx.noise_std_m.get(s.key[1], 0.0)  # type: ignore[operator]

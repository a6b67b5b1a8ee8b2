"""bias: add a constant offset (seed "type A": constant-offset injection)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import model_validator

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase


class BiasRule(RuleBase):
    """``value + offset``; ``offset`` in the field's physical unit (``offset_m`` is accepted as in DESIGN.md)."""

    kind: Literal["bias"] = "bias"
    offset: Finite

    @model_validator(mode="before")
    @classmethod
    def _design_spelling(cls, data: Any) -> Any:
        # DESIGN.md's example writes ``offset_m``; accept it so both spellings work.
        if isinstance(data, dict) and "offset_m" in data and "offset" not in data:
            data = {("offset" if k == "offset_m" else k): v for k, v in data.items()}
        return data


class Bias(Primitive):
    kind = "bias"
    rule_model = BiasRule

    def __init__(self, rule: BiasRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.offset = rule.offset

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value += self.offset

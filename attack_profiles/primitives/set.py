"""set: replace the value with a constant (PX4 "off" for a range sensor reads as 0)."""

from __future__ import annotations

from typing import ClassVar, Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase
from attack_profiles.units import MESSAGES
from secuav_common.loading import InputError


class SetRule(RuleBase):
    """``value := value`` parameter, in the field's physical unit. On a field outside the typed table
    (any message of the dialect) it must be one the field's wire type can carry: refused when the profile
    is read. The typed fields keep their older contract: clamped at the wire, named in ``clamped``."""

    kind: Literal["set"] = "set"
    value: Finite

    clamps_to_limits: ClassVar[bool] = False  # the profile's value, also outside [min, max] ("reads 0")

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        target = self.target
        if target.message is None:
            return
        msg = MESSAGES[target.message]
        name = target.field or msg.default_field or ""
        spec = msg.field(name)
        if spec is None or (not msg.derived and name in msg.fields):  # a typed field: clamped, as before
            return
        if spec.to_wire(self.value)[1]:
            lo, hi = sorted((spec.lo * spec.scale, spec.hi * spec.scale))
            unit = f" {spec.unit}" if spec.unit else ""
            raise InputError(source, f"{where}.value", self.value, f"{msg.name}.{spec.name} ({spec.wire_type}) "
                             f"carries {lo:g} to {hi:g}{unit}")  # fmt: skip


class Set(Primitive):
    kind = "set"
    rule_model = SetRule
    pure = True

    def __init__(self, rule: SetRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.value = rule.value

    def apply(self, s: Sample, tau_s: float | None) -> None:
        s.value = self.value

"""garbage: the field carries random wire values (PX4 "garbage")."""

from __future__ import annotations

from typing import ClassVar, Literal

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import RuleBase
from attack_profiles.units import MessageSpec
from secuav_common.loading import InputError


class GarbageRule(RuleBase):
    """Replace the field with a value drawn uniformly from everything its wire type can carry
    (0..65535 cm for ``current_distance``; any float32 for float fields). ``scope: frame`` does
    this to every attackable field of the message (the sensor id and timestamps stay, so the
    frame still parses and says whose it is; a message outside the typed table: every numeric
    field but its time); the target then names no field."""

    kind: Literal["garbage"] = "garbage"
    scope: Literal["field", "frame"] = "field"

    within_limits: ClassVar[bool] = False  # a sensor gone mad: readings anywhere in the wire range

    def fields_of(self, msg: MessageSpec) -> list[str | None]:
        if self.scope != "frame":
            return super().fields_of(msg)
        return [name for name in msg.fields if name != msg.time_field]  # a dialect message's clock stays

    def names_a_field(self) -> bool:
        return self.scope != "frame"  # every field: LOCAL_POSITION_NED or COMMAND_LONG as a whole

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.scope == "frame" and self.target.field is not None:
            raise InputError(source, f"{where}.target.field", self.target.field, "scope frame covers every field")


class Garbage(Primitive):
    kind = "garbage"
    rule_model = GarbageRule

    def __init__(self, rule: GarbageRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        spec = ctx.spec
        assert spec is not None  # the profile check requires a field for garbage
        self.spec = spec
        self.rng = ctx.rng

    def apply(self, s: Sample, tau_s: float | None) -> None:
        spec = self.spec
        if spec.integer:
            wire: float = self.rng.randint(int(spec.lo), int(spec.hi))
        else:
            wire = self.rng.uniform(spec.lo, spec.hi)
        s.value = spec.to_physical(wire)

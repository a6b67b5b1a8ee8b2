"""freeze: hold the last clean value seen before the window (PX4 "stuck")."""

from __future__ import annotations

from typing import Literal

from attack_profiles.primitives.base import Context, Primitive, Sample, SampleKey
from attack_profiles.rule import RuleBase


class FreezeRule(RuleBase):
    """Inside the window every sample carries the value its target last had before the
    window began (or, if none was seen, the first value inside it). State is per target."""

    kind: Literal["freeze"] = "freeze"


class Freeze(Primitive):
    kind = "freeze"
    rule_model = FreezeRule
    stateful = True

    def __init__(self, rule: FreezeRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.last: dict[SampleKey, float] = {}
        self.held: dict[SampleKey, float] = {}

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if tau_s is None:
            self.last[s.key] = s.value
            # Leaving the window releases the hold, so a repeated window freezes afresh.
            self.held.pop(s.key, None)
            return
        held = self.held.get(s.key)
        if held is None:
            held = self.held[s.key] = self.last.get(s.key, s.value)
        s.value = held

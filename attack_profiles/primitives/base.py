"""The one shape every attack primitive has.

A primitive is built from its validated rule and a :class:`Context` (the field
it acts on, its own seeded random generator, anchor positions) and has one
method, :meth:`Primitive.apply`, that rewrites a :class:`Sample` in place: the
value in physical units, or the frame-level decisions (drop, delay). The sample
also carries what an attacker on the link can know at that moment: the time,
the sample's key, the vehicle's position as last read from its own
LOCAL_POSITION_NED (rules whose model sets ``needs_position``) and the other
fields of the message. The live path and the offline arrays fill the sample the
same way and run the same rule chain, so a new attack is one module. The engine
calls it only for samples the rule's target matches, with ``tau_s`` = time since
the current window occurrence began, or ``None`` outside the window; only
``stateful`` primitives are called outside their window, to watch the clean stream.
"""

from __future__ import annotations

import random
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from attack_profiles.rule import RuleBase
from attack_profiles.units import FieldSpec

Vec3 = tuple[float, float, float]
SampleKey = tuple[int, int]  # (sysid, sensor id or -1): stateful primitives keep state per key

# Times are compared with this slack: "the sample 0.2 s ago" must find the sample stamped
# 0.4 when asked at 0.6, although 0.6 - 0.2 is 0.39999999999999997 in binary floating point.
TIME_EPS_S = 1e-9


@dataclass(slots=True)
class Sample:
    """One value on its way through the rule chain (mutable, reused by the engine)."""

    t_s: float = 0.0  # profile clock
    key: SampleKey = (0, -1)
    value: float = 0.0  # physical units of the targeted field
    drop: bool = False
    delay_s: float = 0.0
    offline: bool = False  # True on the array path: delay acts on the value stream
    # What the attacker on the link knows besides the value (the engine fills these for every rule):
    position_ned_m: Vec3 | None = None  # the vehicle's position as the attacker last read it, None before
    fields: Mapping[str, Any] = field(default_factory=dict)  # the message's fields as received (wire units)
    # Fields of this frame that carry no reading (out of the sensor's range, invalid, no fix): rules with
    # ``out_of_range: keep`` pass them by. ``free``: fields a rule with ``out_of_range: attack`` rewrote.
    unread: frozenset[str] = frozenset()
    free: set[str] = field(default_factory=set)


@dataclass(frozen=True, slots=True)
class Context:
    """What a primitive may know besides its rule."""

    rule_index: int
    spec: FieldSpec | None  # None for frame-level rules
    rng: random.Random
    anchors_ned_m: dict[int, Vec3] = field(default_factory=dict)  # sensor id -> anchor position
    noise_std_m: dict[int, float] = field(default_factory=dict)  # sensor id -> its noise std in the scenario


class Primitive(ABC):
    """Base of every primitive; subclasses set ``kind`` and ``rule_model``."""

    kind: ClassVar[str]
    rule_model: ClassVar[type[RuleBase]]
    stateful: ClassVar[bool] = False  # must see samples outside its window
    # The value it writes is a function of the value it is given and of the sample's key and fields only:
    # not of tau or the time, no randomness, no state, and it neither drops nor delays the frame. The proxy may
    # then repeat a rewrite it saw for later frames with the same payload (Engine.memo_fields); a plugin that
    # does not say so is never repeated.
    pure: ClassVar[bool] = False

    def __init__(self, rule: RuleBase, ctx: Context) -> None:
        self.rule = rule
        self.ctx = ctx

    @abstractmethod
    def apply(self, s: Sample, tau_s: float | None) -> None:
        """Rewrite ``s`` for time ``tau_s`` into the window (``None``: outside it)."""

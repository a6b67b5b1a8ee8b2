"""A profile's frame operations on a live link (``inject``, ``duplicate``, ``frame_replay``, ``mission_shift``).

The engine runs the value rules; this runs the rules whose primitive is a
:class:`~attack_profiles.primitives.frame_op.FrameOp`, in profile order, on the same activation
clock. The proxy's attack stage calls::

    ops = engine.frame_ops                       # None: the profile has no frame operation
    pkts = ops.process(pkt, now_s, vehicle)      # a frame whose id is in ops.message_ids
    pkts = ops.due(now_s, vehicle, link)         # frames made on the clock, when ops.next_due_s says

Everything an operation keeps is per vehicle, so one engine may serve several links. The HEARTBEATs
of the link tell who the ground station and the vehicle's autopilot are (the default ids of a forged
frame), so an ``inject`` rule watches them too.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterable

from attack_profiles.primitives import PRIMITIVES, Context
from attack_profiles.primitives.frame_op import DIRECTIONS, HEARTBEAT_ID, FrameOp, FrameOpRule, LinkView
from attack_profiles.profile import Profile
from attack_profiles.rule import RuleBase
from mavframe.packet import Direction, Packet
from secuav_common.loading import InputError

MAV_AUTOPILOT_INVALID = 8  # a HEARTBEAT from a component that is not an autopilot (camera, gimbal, GCS)


def is_frame_rule(rule: RuleBase) -> bool:
    return isinstance(rule, FrameOpRule)


def needs_key(profile: Profile) -> list[tuple[int, str, frozenset[Direction]]]:
    """(rule index, kind, directions) of every rule that writes frames: on a signed direction it needs the key.

    Frame operations add or rewrite frames; value rules rewrite fields. Drop, delay and intermittent
    only hold frames back and need none."""
    out = []
    for i, rule in enumerate(profile.rules):
        kind = rule.kind  # type: ignore[attr-defined]
        if isinstance(rule, FrameOpRule):
            out.append((i, kind, rule.directions))
        elif not rule.frame_level:
            out.append((i, kind, DIRECTIONS[rule.target.direction]))
    return out


def value_warnings(profile: Profile, warn: object) -> list[str]:
    """``warn(profile)`` (the true-copy check) over the value rules only, ``rules[i]`` keeping profile indices."""
    kept = [i for i, r in enumerate(profile.rules) if not is_frame_rule(r)]
    if len(kept) == len(profile.rules):
        return list(warn(profile))  # type: ignore[operator]
    view = profile.model_copy(update={"rules": [profile.rules[i] for i in kept]})
    return [re.sub(r"rules\[(\d+)\]", lambda m: f"rules[{kept[int(m.group(1))]}]", w)
            for w in warn(view)]  # type: ignore[operator]  # fmt: skip


class FrameOps:
    """The frame operations of one profile (see the module doc)."""

    def __init__(self, profile: Profile, seed: int = 0) -> None:
        self.profile = profile
        self.seed = seed
        if profile.clock != "activation":
            i = next(i for i, r in enumerate(profile.rules) if is_frame_rule(r))
            raise InputError(profile.source, f"rules[{i}].kind", profile.rules[i].kind,  # type: ignore[attr-defined]
                             "frame operations run on the activation clock: use clock: activation")  # fmt: skip
        self.ops: list[FrameOp] = []
        for i, rule in enumerate(profile.rules):
            if is_frame_rule(rule):
                cls = PRIMITIVES[rule.kind]  # type: ignore[attr-defined]
                self.ops.append(cls(rule, Context(i, None, random.Random(seed + i))))  # type: ignore[arg-type]
        ids: set[int] = set().union(*(op.message_ids for op in self.ops if op.kind != "inject"))
        if any(op.kind == "inject" for op in self.ops):
            ids.add(HEARTBEAT_ID)  # who the ground station and the autopilot are: a forged frame's default ids
        self.message_ids: frozenset[int] = frozenset(ids)
        self.forges: frozenset[Direction] = frozenset().union(
            *(op.directions for op in self.ops if op.kind != "mission_shift")
        )
        self.timed = any(op.kind in ("inject", "frame_replay") for op in self.ops)
        self.active_at_s: float | None = None
        self._views: dict[int, LinkView] = {}

    @classmethod
    def of(cls, profile: Profile, seed: int = 0) -> FrameOps | None:
        """The profile's frame operations, or None when it has none (the usual case)."""
        return cls(profile, seed) if any(is_frame_rule(r) for r in profile.rules) else None

    def activate(self, now_s: float) -> None:
        """Start the clock (and forget everything, as the engine's state does)."""
        fresh = FrameOps(self.profile, self.seed)
        self.ops, self._views = fresh.ops, {}
        self.active_at_s = now_s

    def view(self, vehicle: int, link: int = 0) -> LinkView:
        v = self._views.get(vehicle)
        if v is None:
            v = self._views[vehicle] = LinkView(vehicle, link)
        return v

    def _t(self, now_s: float) -> float:
        if self.active_at_s is None:
            self.active_at_s = now_s
        return now_s - self.active_at_s

    def process(self, pkt: Packet, now_s: float, vehicle: int) -> list[Packet]:
        """The packets one received frame becomes: it (perhaps changed), its copies; ``[]`` if replaced."""
        view = self.view(vehicle, pkt.link)
        h = pkt.header
        if h.msgid == HEARTBEAT_ID and pkt.fields is not None:
            if pkt.direction is Direction.UPLINK:
                view.ground = (h.sysid, h.compid)
            elif h.sysid == vehicle and pkt.fields.get("autopilot") != MAV_AUTOPILOT_INVALID:
                view.autopilot = (h.sysid, h.compid)
            if view.waiting:
                view.waiting = False
                view.rescheduled = True
        t = self._t(now_s)
        pkts = [pkt]
        for op in self.ops:
            if h.msgid in op.message_ids:
                pkts = op.on_frame(pkts, t, view)
        return pkts

    def rescheduled(self, vehicle: int) -> bool:
        """True once after a frame changed what is due next (a recording began)."""
        v = self._views.get(vehicle)
        if v is None or not v.rescheduled:
            return False
        v.rescheduled = False
        return True

    def next_due_s(self, vehicle: int) -> float | None:
        """Monotonic time of the next frame :meth:`due` makes for ``vehicle``, or None."""
        if not self.timed:
            return None
        view = self.view(vehicle)
        times = [t for t in (op.next_due(view) for op in self.ops) if t is not None]
        if not times:
            return None
        if self.active_at_s is None:
            return None  # not started: nothing is due before the first frame or tick starts the clock
        return self.active_at_s + min(times)

    def due(self, now_s: float, vehicle: int, link: int) -> list[Packet]:
        view = self.view(vehicle, link)
        view.link = link
        t = self._t(now_s)
        out: list[Packet] = []
        for op in self.ops:
            made = op.due(t, view, now_s)
            if made:
                view.counts[op.kind] = view.counts.get(op.kind, 0) + len(made)
                out.extend(made)
        return out

    def counts(self, vehicles: Iterable[int] | None = None) -> dict[str, int]:
        """Frames made so far, per rule kind (all vehicles, or these)."""
        out: dict[str, int] = {}
        for sysid, v in self._views.items():
            if vehicles is None or sysid in vehicles:
                for k, n in v.counts.items():
                    out[k] = out.get(k, 0) + n
        return out

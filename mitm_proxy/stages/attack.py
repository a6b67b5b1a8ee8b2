"""The attack stage: runs the slot's attack_profiles engine on the frames it targets.

The pipeline hands this stage only frames whose message id the active profile
targets (``message_ids`` comes from the engine), so only those are decoded. The
engine's :class:`~attack_profiles.action.Action` maps onto the packet:

- ``drop`` -> ``[]``;
- ``fields`` -> merged into ``pkt.fields``, ``changed`` set (the pipeline re-packs
  with the original sysid, compid, seq and a fresh CRC);
- ``delay_s`` -> ``release_s = now + delay_s``.

Every acting rule is noted on the packet as ``attack:<profile>:rules[<i>]`` for the
recording index. The slot's ``message_ids`` also hold, until each is seen once, the
messages that may carry a true copy of what the profile attacks
(:mod:`mitm_proxy.stages.true_copy_watch`): such a frame is told to the slot and
passes as it came, undecoded. ``active = False`` is the seed's bypass; with no profile in
the slot the stage is inactive too, so the pipeline skips it for free.

The profile's frame operations (``engine.frame_ops``: inject, duplicate, frame_replay,
mission_shift) run after the value rules on the frames they target, and on the clock through
:meth:`AttackStage.due` / :meth:`AttackStage.next_due_s`, which the pipeline's ``tick`` asks.
Whoever drives the clock (the link) sets :attr:`AttackStage.on_schedule`; the stage calls it when
what is due may have changed: a profile installed or cleared, the bypass switched, a recording begun.

Repeated rewrites: for a frame of a message in :attr:`AttackStage.memo_fields` (the engine's
``memo_fields`` less the carriers still watched), the stage sets ``pkt.steady_until_s`` to the engine's
``steady_until``: until then every frame of the same message, sysid and direction whose payload, less
the field named there (its time field, or none), is this one's gets this one's verdict, so the pipeline's
fast route may repeat the rewrite without the stage (mitm_proxy/README.md, "The fast path"). A frame
dropped or delayed is never repeated. What was learnt so stands while :attr:`AttackStage.memo_token` does
not change (another profile, the same one restarted).
"""

from __future__ import annotations

from collections.abc import Callable

from attack_profiles.engine import Engine
from mavframe import codec
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.stages.attack_slot import AttackSlot

__all__ = ["AttackStage"]


class AttackStage:
    """Stage ``attack`` of one link, reading its profile from ``slot`` at every frame."""

    name = "attack"

    def __init__(self, slot: AttackSlot, *, active: bool = True) -> None:
        self.slot = slot
        self._enabled = active
        self.on_schedule: Callable[[], None] | None = None
        self._token: tuple[Engine, int] | None = None
        slot.listeners.append(self._rescheduled)

    @property
    def active(self) -> bool:
        """False when bypassed or when no profile is installed."""
        return self._enabled and self.slot.engine is not None  # per datagram: no property call inside

    @active.setter
    def active(self, value: bool) -> None:
        self.enabled = value

    @property
    def enabled(self) -> bool:
        """False while bypassed (the ``attack/mode`` switch writes it); a change re-arms the link's clock."""
        return self._enabled

    @enabled.setter
    def enabled(self, value: bool) -> None:
        changed = value != self._enabled
        self._enabled = value
        if changed:
            self._rescheduled()

    def _rescheduled(self) -> None:
        if self.on_schedule is not None:
            self.on_schedule()

    @property
    def forges(self) -> frozenset[Direction]:
        """Directions the profile adds frames to (their sequence numbers must be watched)."""
        engine = self.slot.engine
        ops = None if engine is None else engine.frame_ops
        return frozenset() if ops is None else ops.forges

    def next_due_s(self) -> float | None:
        engine = self.slot.engine
        ops = None if engine is None else engine.frame_ops
        return None if ops is None else ops.next_due_s(self.slot.sysid)

    def due(self, now_s: float, link: int) -> list[Packet]:
        engine = self.slot.engine
        ops = None if engine is None else engine.frame_ops
        if ops is None:
            return []
        pkts = ops.due(now_s, self.slot.sysid, link)
        if pkts:
            prefix = f"attack:{engine.profile.name}:"  # type: ignore[union-attr]
            for p in pkts:
                p.notes[:] = [prefix + n for n in p.notes]
        return pkts

    @property
    def message_ids(self) -> frozenset[int]:
        return self.slot.message_ids

    @property
    def field_filters(self) -> dict[int, tuple[str, frozenset[int]]]:
        """Of ``message_ids``, the ones wanted only for a few values of an id field (the pipeline's module doc)."""
        return self.slot.field_filters

    @property
    def memo_fields(self) -> dict[int, str | None]:
        """Of ``message_ids``, those whose verdict the fast route may repeat until ``pkt.steady_until_s``:
        ``msgid -> the field left out of the key`` (None: the whole payload); the same dict while nothing
        changed."""
        return self.slot.memo_fields

    @property
    def memo_token(self) -> object:
        """Changes (by ``==`` and by identity) whenever a verdict learnt before may no longer hold: another
        engine, or the same one activated again. None without a profile."""
        engine = self.slot.engine
        if engine is None:
            return None
        token = self._token
        if token is None or token[0] is not engine or token[1] != engine.epoch:
            token = self._token = (engine, engine.epoch)
        return token

    def signed_untouched(self, header: Header) -> None:
        """The pipeline left a signed frame the profile targets alone (no key): the slot's state says so.

        A watched carrier (a true copy the profile does not target) counts as seen: signed or not, it is on the
        wire carrying the truth, and it is watched for no longer."""
        slot = self.slot
        if header.msgid in slot.watching:  # (the pipeline does not say the direction: carriers are the vehicle's)
            slot.saw(header.msgid)
            engine = slot.engine
            if engine is None or header.msgid not in engine.message_ids:
                return
        slot.signed_untouched(header.sysid, header.msgid)

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        engine = self.slot.engine
        if engine is None:  # cleared between the pipeline's check and now
            return [pkt]
        h = pkt.header
        if h.msgid in self.slot.watching and pkt.direction is Direction.DOWNLINK:
            self.slot.saw(h.msgid)
            if h.msgid not in engine.message_ids:
                return [pkt]
        fields = codec.decode(pkt)
        action = engine.process(now_s, h.msgid, fields, pkt.direction, h.sysid, h.compid)
        if h.msgid in self.slot.memo_fields and not (action.drop or action.delay_s > 0.0):
            # (asked of the frame as it came, before its fields take the rewrite)
            pkt.steady_until_s = engine.steady_until(now_s, h.msgid, fields, pkt.direction, h.sysid)
        ops = engine.frame_ops
        if not action.untouched:
            notes = [f"attack:{engine.profile.name}:rules[{i}]" for i in action.rules]
            if action.drop:
                pkt.notes.extend(notes)
                return []
            if action.fields:
                fields.update(action.fields)
                pkt.changed = True
            if action.clamped:
                notes.append("clamped:" + ",".join(action.clamped))
            if action.delay_s > 0.0:
                pkt.release_s = max(pkt.release_s, now_s + action.delay_s)
            pkt.notes.extend(notes)
        if ops is None or h.msgid not in ops.message_ids:
            return [pkt]
        before = len(pkt.notes)
        pkts = ops.process(pkt, now_s, self.slot.sysid)
        prefix = f"attack:{engine.profile.name}:"
        for p in pkts:
            start = before if p is pkt else 0
            p.notes[start:] = [n if n.startswith("attack:") else prefix + n for n in p.notes[start:]]
        if ops.rescheduled(self.slot.sysid):
            self._rescheduled()
        return pkts

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
"""

from __future__ import annotations

from mavframe import codec
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.stages.attack_slot import AttackSlot

__all__ = ["AttackStage"]


class AttackStage:
    """Stage ``attack`` of one link, reading its profile from ``slot`` at every frame."""

    name = "attack"

    def __init__(self, slot: AttackSlot, *, active: bool = True) -> None:
        self.slot = slot
        self.enabled = active

    @property
    def active(self) -> bool:
        """False when bypassed or when no profile is installed."""
        return self.enabled and self.slot.engine is not None

    @active.setter
    def active(self, value: bool) -> None:
        self.enabled = value

    @property
    def message_ids(self) -> frozenset[int]:
        return self.slot.message_ids

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
        if action.untouched:
            return [pkt]
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
        return [pkt]

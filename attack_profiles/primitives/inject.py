"""inject: the proxy sends a message nobody sent (MAVProxy's ``long`` command, a forged RTL, a fake HEARTBEAT)."""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field, JsonValue

from attack_profiles.primitives.frame_op import (
    AUTOPILOT_COMPID,
    GCS_IDS,
    FrameOp,
    FrameOpRule,
    LinkView,
    codec_module,
    message_class,
    resolve_fields,
)
from mavframe.packet import Direction, Packet
from secuav_common.loading import InputError

SysId = Annotated[int, Field(ge=1, le=255)]
# With default ids, a frame waits (at most this long after start_s) until the sender it impersonates has been
# heard since the profile began: its next sequence number is known only then.
HEAR_WAIT_S = 1.5
CompId = Annotated[int, Field(ge=0, le=255)]


class InjectRule(FrameOpRule):
    """Send ``target.message`` with ``fields`` in ``target.direction`` (uplink: to the vehicle; downlink:
    to the ground) from ``start_s``: once, or at ``rate_hz`` until ``count`` were sent or ``end_s``.

    ``fields`` take wire units and enum names (``command: MAV_CMD_NAV_RETURN_TO_LAUNCH``; a list of
    names ORs a bitmask); fields left out are 0, and ``target_system`` / ``target_component`` the
    link's vehicle and its autopilot (uplink) or the ground station last heard (downlink). The frame
    comes from ``from_sysid``/``from_compid``: by default (uplink) the ground station whose HEARTBEAT
    the proxy last saw on the link, else 255/190, or (downlink) the vehicle's autopilot; a frame with
    default ids waits, up to 1.5 s after its time, until that sender was heard, so that it takes the
    sender's next sequence number."""

    kind: Literal["inject"] = "inject"
    selects: ClassVar[bool] = False
    fields: dict[str, JsonValue] = Field(default_factory=dict, description="the message's fields (wire units, enums)")
    rate_hz: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)] | None = Field(
        None, description="frames a second from start_s; none: one frame"
    )
    count: Annotated[int, Field(ge=1, le=10_000_000)] | None = Field(None, description="with rate_hz: stop after n")
    from_sysid: SysId | None = Field(None, description="sender sysid; default: the ground station heard, the vehicle")
    from_compid: CompId | None = Field(None, description="sender compid; default as from_sysid (else 190 up, 1 down)")

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.target.direction == "both":
            raise InputError(source, f"{where}.target.direction", "both", "inject goes one way: uplink or downlink")
        if self.count is not None and self.rate_hz is None:
            raise InputError(source, f"{where}.count", self.count, "a count needs rate_hz (without it: one frame)")
        assert self.target.message is not None
        cls = message_class(self.target.message, f"{where}.target.message", source)
        values = resolve_fields(cls, self.fields, f"{where}.fields", source)
        codec = codec_module()
        try:  # every value packs: out-of-range floats, wrong arrays, ... are found now, not on the link
            codec.build(cls.msgname, _complete(cls, values, (1, 1)), sysid=1, compid=1, seq=0,
                        direction=Direction.UPLINK, link=0, now_s=0.0)  # fmt: skip
        except codec.EncodeError as exc:
            raise InputError(source, f"{where}.fields", dict(self.fields), str(exc)) from None


def _complete(cls: Any, values: dict[str, Any], target: tuple[int, int]) -> dict[str, Any]:
    """Every field of ``cls``: the given ones, the target ids, 0 for the rest (``mavlink_version`` 3)."""
    out: dict[str, Any] = {}
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        if ftype == "char":
            out[name] = ""
        elif lengths[name]:
            out[name] = [0] * lengths[name]
        else:
            out[name] = 3 if name == "mavlink_version" else 0  # HEARTBEAT: the protocol version, always 3
    if "target_system" in out:
        out["target_system"], out["target_component"] = target
    out.update(values)
    return out


class Inject(FrameOp):
    kind = "inject"
    rule_model = InjectRule

    def __init__(self, rule: InjectRule, ctx: Any) -> None:
        super().__init__(rule, ctx)
        assert rule.target.message is not None
        self.cls = message_class(rule.target.message, "target.message", "<rule>")
        self.values = resolve_fields(self.cls, rule.fields, "fields", "<rule>")
        self.period_s = None if rule.rate_hz is None else 1.0 / rule.rate_hz
        self.limit = rule.count if rule.rate_hz is not None else 1
        self.direction = Direction.UPLINK if rule.target.direction == "uplink" else Direction.DOWNLINK
        self._next: dict[int, float] = {}  # vehicle -> profile time of its next frame
        self._sent: dict[int, int] = {}

    def _ids(self, view: LinkView) -> tuple[tuple[int, int], tuple[int, int]]:
        """(sender, target) ids of the next frame on ``view``'s link."""
        r: InjectRule = self.rule  # type: ignore[assignment]
        ground = view.ground or GCS_IDS
        vehicle = view.autopilot or (view.vehicle, AUTOPILOT_COMPID)
        if self.direction is Direction.UPLINK:
            sender, target = ground, (view.vehicle, AUTOPILOT_COMPID)
        else:
            sender, target = vehicle, view.ground or (0, 0)
        return (r.from_sysid or sender[0], sender[1] if r.from_compid is None else r.from_compid), target

    def _heard(self, view: LinkView) -> bool:
        r: InjectRule = self.rule  # type: ignore[assignment]
        if r.from_sysid is not None:
            return True  # a sender of the profile's choosing: nothing to wait for
        return (view.ground if self.direction is Direction.UPLINK else view.autopilot) is not None

    def next_due(self, view: LinkView) -> float | None:
        if self.limit is not None and self._sent.get(view.vehicle, 0) >= self.limit:
            return None
        t = self._next.get(view.vehicle, self.start_s)
        if not self._heard(view) and view.vehicle not in self._sent:
            view.waiting = True  # the first HEARTBEAT of the sender re-arms the clock
            t += HEAR_WAIT_S
        return t if t < self.end_s else None

    def due(self, t_s: float, view: LinkView, now_s: float) -> list[Packet]:
        at = self.next_due(view)
        if at is None or at > t_s:
            return []
        sender, target = self._ids(view)
        pkt = codec_module().build(self.cls.msgname, _complete(self.cls, self.values, target), sysid=sender[0],
                          compid=sender[1], seq=0, direction=self.direction, link=view.link, now_s=now_s)  # fmt: skip
        pkt.origin = "inject"
        pkt.notes.append(self.note)
        self._sent[view.vehicle] = self._sent.get(view.vehicle, 0) + 1
        nxt = math.inf if self.period_s is None else at + self.period_s
        if nxt <= t_s:  # the timer came late by more than a period: no burst, the rate goes on from now
            nxt = t_s + self.period_s  # type: ignore[operator]
        self._next[view.vehicle] = nxt
        return [pkt]

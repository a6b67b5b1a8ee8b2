"""What every frame operation has: a target by message name, and whole frames instead of values.

The value primitives (bias, replay, ...) rewrite a number inside a frame that passes. Frame
operations add frames (``inject``, ``duplicate``, ``frame_replay``) or follow a protocol exchange
(``mission_shift``). They take any message of the dialect the proxy speaks (MAVLink common +
ardupilotmega), run on the activation clock, and act on live links only: the offline arrays
(:meth:`~attack_profiles.engine.Engine.apply_array`) have no frames to add. They work on
:class:`mavframe.packet.Packet` objects; the proxy renumbers and signs what they add.

A frame operation's ``target.sysid`` is the vehicle of the link (downlink frames from it, uplink
frames to it), not the sender of the frame: one proxy link carries one vehicle. ``target.where``
narrows ``duplicate`` and ``frame_replay`` to frames whose fields hold given values
(``{command: MAV_CMD_NAV_TAKEOFF}``), as for value rules.
"""

from __future__ import annotations

import difflib
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, ClassVar

from attack_profiles.primitives.base import Primitive, Sample
from attack_profiles.rule import RuleBase, Target
from attack_profiles.units import MESSAGES
from attack_profiles.where import Match, check_where, matches, resolve_where
from mavframe.packet import Direction, Packet
from secuav_common.loading import _MISSING, InputError

DIRECTIONS: dict[str, frozenset[Direction]] = {
    "downlink": frozenset((Direction.DOWNLINK,)),
    "uplink": frozenset((Direction.UPLINK,)),
    "both": frozenset((Direction.DOWNLINK, Direction.UPLINK)),
}
GCS_IDS = (255, 190)  # forged uplink frames come from here until a ground station's HEARTBEAT says otherwise
AUTOPILOT_COMPID = 1  # MAV_COMP_ID_AUTOPILOT1
HEARTBEAT_ID = 0
_INT_RANGES = {"int8_t": (-(2**7), 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-(2**15), 2**15 - 1),
               "uint16_t": (0, 2**16 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint32_t": (0, 2**32 - 1),
               "int64_t": (-(2**63), 2**63 - 1), "uint64_t": (0, 2**64 - 1),
               "uint8_t_mavlink_version": (0, 255)}  # fmt: skip


# pymavlink's dialect (and mavframe.codec, built on it) take a while to import: only when a frame
# operation is used, so importing attack_profiles stays light.
def codec_module() -> ModuleType:
    from mavframe import codec

    return codec


@functools.cache
def _enum_values() -> dict[str, int]:
    dialect = codec_module().dialect
    return {e.name: v for entries in dialect.enums.values() for v, e in entries.items()}


def message_id(name: str) -> int:
    return int(codec_module().BY_NAME[name].id)


def closest(word: str, options: list[str] | tuple[str, ...]) -> str:
    near = difflib.get_close_matches(word, options, n=3, cutoff=0.5)
    return f" (closest: {', '.join(near)})" if near else ""


def message_class(name: str, where: str, source: str) -> Any:
    """The dialect's class of message ``name``; ``InputError`` at ``where`` naming the closest names."""
    codec = codec_module()
    cls = codec.BY_NAME.get(name)
    if cls is None:
        raise InputError(source, where, name, "not a MAVLink message of common/ardupilotmega"
                         + closest(name, list(codec.BY_NAME)))  # fmt: skip
    return cls


def resolve_fields(cls: Any, given: Mapping[str, Any], where: str, source: str) -> dict[str, Any]:
    """Profile values of ``cls``'s fields in wire form: enum names become numbers (a list of names of a
    bitmask ORs them), integers are range-checked, char arrays are text; ``InputError`` names the field."""
    out: dict[str, Any] = {}
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    for name, value in given.items():
        at = f"{where}.{name}"
        if name not in cls.fieldnames:
            raise InputError(source, at, value, f"{cls.msgname} has no such field" + closest(name, cls.fieldnames))
        ftype = cls.fieldtypes[cls.fieldnames.index(name)]
        n = lengths[name]
        if ftype == "char":
            if not isinstance(value, str) or len(value.encode()) > n:
                raise InputError(source, at, value, f"text of at most {n} characters")
            out[name] = value
        elif n:
            if not isinstance(value, list) or len(value) != n:
                raise InputError(source, at, value, f"a list of {n} numbers")
            out[name] = [_scalar(cls, name, ftype, v, f"{at}[{i}]", source) for i, v in enumerate(value)]
        else:
            out[name] = _scalar(cls, name, ftype, value, at, source)
    return out


def _scalar(cls: Any, name: str, ftype: str, value: Any, at: str, source: str) -> Any:
    enum = cls.fieldenums_by_name.get(name)
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):  # bitmask: OR the names
        total = 0
        for v in value:
            total |= _enum_value(enum, v, at, source)
        value = total
    elif isinstance(value, str):
        value = _enum_value(enum, value, at, source)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(source, at, value, "a number or an enum name")
    bounds = _INT_RANGES.get(ftype)
    if bounds is None:
        if not math.isfinite(value):
            raise InputError(source, at, value, "not a finite number")
        return float(value)
    if isinstance(value, float) and not value.is_integer():
        raise InputError(source, at, value, f"{ftype} takes whole numbers")
    if not bounds[0] <= value <= bounds[1]:
        raise InputError(source, at, value, f"out of {ftype}'s range {bounds[0]}..{bounds[1]}")
    return int(value)


def _enum_value(enum: str | None, name: str, at: str, source: str) -> int:
    """``name`` in the field's enum, or (a field with none, e.g. a COMMAND_LONG param) any enum of the dialect."""
    if enum is not None:
        enums = codec_module().dialect.enums[enum]
        entries = {e.name: v for v, e in enums.items() if not e.name.endswith("_ENUM_END")}
        if name not in entries:
            raise InputError(source, at, name, f"not a {enum} name" + closest(name, list(entries)))
        return entries[name]
    values = _enum_values()
    if name not in values:
        raise InputError(source, at, name, "not an enum name of the dialect" + closest(name, list(values)))
    return values[name]


@dataclass(slots=True)
class LinkView:
    """What a frame operation may know of the link it acts on (the proxy fills it, per vehicle)."""

    vehicle: int  # the link's vehicle sysid
    link: int = 0  # the pipeline's link index (for the packets it builds)
    ground: tuple[int, int] | None = None  # (sysid, compid) of the last uplink HEARTBEAT, the ground station
    autopilot: tuple[int, int] | None = None  # (sysid, compid) of the vehicle's autopilot HEARTBEAT
    rescheduled: bool = False  # set by an operation whose next due time changed on a frame
    waiting: bool = False  # an injection waits for its sender's HEARTBEAT: hearing it reschedules
    counts: dict[str, int] = field(default_factory=dict)  # per rule kind: frames made


class FrameOpRule(RuleBase):
    """Base of frame-operation rules: a message target, without field or sensor id."""

    target: Target

    frame_level: ClassVar[bool] = True
    selects: ClassVar[bool] = True  # acts on received frames, so target.where may narrow them

    def check(self, where: str, source: str) -> None:
        t = self.target
        if t.quantity is not None:
            raise InputError(source, f"{where}.target.quantity", t.quantity, f"{self.kind} targets a message")  # type: ignore[attr-defined]
        if t.sensor_id is not None:
            raise InputError(source, f"{where}.target.sensor_id", t.sensor_id, f"{self.kind} acts on whole frames")  # type: ignore[attr-defined]
        if t.field is not None:
            raise InputError(source, f"{where}.target.field", t.field, f"{self.kind} acts on whole frames")  # type: ignore[attr-defined]
        if t.message is None:
            raise InputError(source, f"{where}.target.message", _MISSING, "name the message")
        message_class(t.message, f"{where}.target.message", source)
        if t.where is not None:
            if not self.selects:
                raise InputError(source, f"{where}.target.where", t.where, f"{self.kind} does not select frames")  # type: ignore[attr-defined]
            check_where(MESSAGES[t.message], t.where, f"{where}.target.where", source)
        self._check_window(where, source)
        if self.repeat_period_s is not None:
            raise InputError(source, f"{where}.repeat_period_s", self.repeat_period_s,
                             f"{self.kind} runs once from start_s; a repeating window is for value rules")  # fmt: skip

    @property
    def directions(self) -> frozenset[Direction]:
        return DIRECTIONS[self.target.direction]


class FrameOp(Primitive):
    """Base of the frame operations (see the module doc); ``t_s`` is the activation clock."""

    frame_op: ClassVar[bool] = True
    rule: FrameOpRule

    def __init__(self, rule: FrameOpRule, ctx: Any) -> None:
        super().__init__(rule, ctx)
        self.index = ctx.rule_index
        self.start_s = rule.start_s
        self.end_s = math.inf if rule.end_s is None else rule.end_s
        self.directions = rule.directions
        msg = rule.target.message
        self.msgid = -1 if msg is None else message_id(msg)
        self.note = f"rules[{self.index}]"
        where = rule.target.where
        self.match: Match | None = None
        if where is not None and msg is not None:
            self.match = resolve_where(MESSAGES[msg], where, f"rules[{self.index}].target.where", "<rule>")

    @property
    def message_ids(self) -> frozenset[int]:
        return frozenset((self.msgid,))

    def applies(self, pkt: Packet, view: LinkView) -> bool:
        """This frame is the target's: message, direction, and the link's vehicle."""
        sysid = self.rule.target.sysid
        if pkt.header.msgid != self.msgid or pkt.direction not in self.directions:
            return False
        if sysid is not None and sysid != view.vehicle:
            return False
        return self.match is None or (pkt.fields is not None and matches(self.match, pkt.fields))

    def on_frame(self, pkts: list[Packet], t_s: float, view: LinkView) -> list[Packet]:
        """The packets one received frame became so far (it first); returns them, changed or added to."""
        return pkts

    def due(self, t_s: float, view: LinkView, now_s: float) -> list[Packet]:
        """Frames due at ``t_s`` (``now_s``: the caller's monotonic clock, for the packets)."""
        return []

    def next_due(self, view: LinkView) -> float | None:
        """Profile-clock time of the next frame :meth:`due` will make, or None."""
        return None

    def apply(self, s: Sample, tau_s: float | None) -> None:
        raise TypeError(f"{self.kind} acts on frames, not on values")  # the engine never calls it

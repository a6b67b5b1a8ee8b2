"""Per-endpoint routing rules: allow/deny by message, sysid and compid, and listen-only ground stations.

What mavlink-router users ask for (its AllowMsgIdOut/BlockMsgIdOut, AllowSrcSysOut, ... per endpoint)
and a spectator GCS that sees the telemetry but can never command the vehicle. Directions are
MAVLink's, not the socket's: ``down`` is vehicle -> ground, ``up`` is ground -> vehicle, so a rule
means the same on a vehicle endpoint (where down is what it receives) and a ground one (where down is
what it is sent).

A frame passes a filter when every non-empty ``allow_*`` list holds it and no ``deny_*`` list does;
``sysid``/``compid`` are the frame's source (its header). ``listen_only`` drops everything a ground
endpoint sends towards the vehicle. Rules are URL options, the same on the command line and in
the config file's ``vehicle:``/``ground:`` URLs::

    --ground 'tcpin://0.0.0.0:5760?listen_only=true'
    --ground 'udpout://127.0.0.1:14550?deny=DISTANCE_SENSOR,ATTITUDE'     # downlink
    --ground 'udpin://127.0.0.1:14551?allow_up=HEARTBEAT,76&deny_sysid_up=7'

In the config file an endpoint may also be written in the long form, rules as a mapping
(``secuav-proxy --print-config`` shows every endpoint that way)::

    ground:
      - url: tcpin://0.0.0.0:5760
        rules: {listen_only: true, down: {deny: [DISTANCE_SENSOR, ATTITUDE]}}

At runtime the rules of any endpoint are replaced over MQTT (``secuav/proxy/<instance>/routes/set``,
acknowledged on ``.../routes/state``; a rejected set changes nothing) or from the command line::

    secuav-attack routes show
    secuav-attack routes set ground:14550 'deny=ATTITUDE&listen_only=true'
    secuav-attack routes set ground:14550 none          # lift every rule

Filtering a datagram splits it (the CRC-checked splitter, so bytes crafted to hide a frame from the
filter are dropped rather than passed) and sends the frames that pass, in order; a datagram whose
frames all pass goes on byte for byte. Every drop is counted under the rule that made it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl

from pydantic import BaseModel, ConfigDict, Field, field_validator

from mavframe import frames
from mavframe.codec import BY_NAME, MAVLINK_MAP
from mavframe.packet import Direction
from secuav_common.loading import InputError, validate
from secuav_common.urls import Endpoint

# The rules say "down" (vehicle -> ground) and "up" (ground -> vehicle), as users write them.
RULE_SIDE: dict[Direction, str] = {Direction.DOWNLINK: "down", Direction.UPLINK: "up"}
_LISTS = ("allow", "deny", "allow_sysid", "deny_sysid", "allow_compid", "deny_compid")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FrameFilter(_Strict):
    """One direction's rules; empty lists leave everything through."""

    allow: list[str | int] = Field(default_factory=list, description="message names or ids to keep (others dropped)")
    deny: list[str | int] = Field(default_factory=list, description="message names or ids to drop")
    allow_sysid: list[int] = Field(default_factory=list, description="source system ids to keep")
    deny_sysid: list[int] = Field(default_factory=list, description="source system ids to drop")
    allow_compid: list[int] = Field(default_factory=list, description="source component ids to keep")
    deny_compid: list[int] = Field(default_factory=list, description="source component ids to drop")

    @field_validator("allow", "deny")
    @classmethod
    def _messages(cls, v: list[str | int]) -> list[str | int]:
        for item in v:
            message_of(item)
        return v

    @field_validator("allow_sysid", "deny_sysid", "allow_compid", "deny_compid")
    @classmethod
    def _ids(cls, v: list[int]) -> list[int]:
        for item in v:
            if not 0 <= item <= 255:
                raise ValueError(f"{item} is not a MAVLink id (0..255)")
        return v

    @property
    def empty(self) -> bool:
        return not any(getattr(self, name) for name in _LISTS)


class EndpointRules(_Strict):
    """What one endpoint may send and receive."""

    listen_only: bool = Field(False, description="nothing from this ground endpoint reaches the vehicle")
    down: FrameFilter = Field(default_factory=FrameFilter, description="vehicle -> ground")
    up: FrameFilter = Field(default_factory=FrameFilter, description="ground -> vehicle")

    @property
    def empty(self) -> bool:
        return not self.listen_only and self.down.empty and self.up.empty


NO_RULES = EndpointRules()


def message_of(item: str | int) -> int:
    """A message name (``DISTANCE_SENSOR``) or id (``132``, also as text) -> its id; ``ValueError`` otherwise."""
    if isinstance(item, int) or item.strip().isdigit():
        msgid = int(item)
        if msgid not in MAVLINK_MAP:
            raise ValueError(f"message id {msgid} is not in the MAVLink dialect")
        return msgid
    cls = BY_NAME.get(item.strip().upper())
    if cls is None:
        raise ValueError(f"{item!r} is not a MAVLink message name")
    return int(cls.id)


def rules_from_options(endpoint: Endpoint, source: str = "<url>") -> EndpointRules:
    """The rules a URL's options give (``listen_only``, ``allow``, ``deny_up``, ``allow_sysid``, ...).

    Unknown options and bad values raise :class:`InputError` naming the URL and the option. Settings of the
    endpoint itself (``ENDPOINT_SETTINGS``: ``max_clients`` of a ``tcpin`` server, ...) are not rules and are
    left to the endpoint.
    """
    pairs = [(k, v) for k, v in endpoint.options if (endpoint.mode, k) not in ENDPOINT_SETTINGS]
    return rules_from_pairs(pairs, f"{endpoint} option", source, f"{source} {endpoint.without_options()}")


# (scheme, URL option) read by the endpoint, not a routing rule
ENDPOINT_SETTINGS = {("tcpin", "max_clients"), ("tcpin", "max_clients_per_address"), ("tcpin", "idle_s")}


def rules_from_query(query: str, source: str) -> EndpointRules:
    """The same rules written as a URL query alone (``deny=ATTITUDE&listen_only=true``; ``""`` is no rule)."""
    try:
        pairs = parse_qsl(query.lstrip("?"), keep_blank_values=True, strict_parsing=bool(query.strip("?")))
    except ValueError:
        raise InputError(source, "rules", query, "not KEY=VALUE pairs joined by &") from None
    return rules_from_pairs(pairs, "option", source, source)


def rules_from_pairs(pairs: Iterable[tuple[str, str]], what: str, source: str, where: str) -> EndpointRules:
    data: dict[str, Any] = {"down": {}, "up": {}}
    for key, value in pairs:
        base, up = (key[:-3], True) if key.endswith("_up") else (key, False)
        if key == "listen_only":
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise InputError(source, f"{what} listen_only", value, "must be true or false")
            data["listen_only"] = value.lower() in ("true", "1", "yes")
        elif base in _LISTS:
            data["up" if up else "down"][base] = [s.strip() for s in value.split(",") if s.strip()]
        else:
            known = ", ".join(("listen_only", *_LISTS, *(f"{k}_up" for k in _LISTS)))
            raise InputError(source, f"{what} {key}", value, f"unknown option (known: {known})")
    return validate(EndpointRules, data, where)


def rules_to_query(rules: EndpointRules) -> str:
    """The URL-option spelling of ``rules`` (what ``secuav-attack routes show`` prints)."""
    parts = ["listen_only=true"] if rules.listen_only else []
    for direction, suffix in (("down", ""), ("up", "_up")):
        flt: FrameFilter = getattr(rules, direction)
        for name in _LISTS:
            items = getattr(flt, name)
            if items:
                parts.append(f"{name}{suffix}={','.join(str(i) for i in items)}")
    return "&".join(parts)


@dataclass(frozen=True, slots=True)
class CompiledFilter:
    """A :class:`FrameFilter` as sets, checked per frame header."""

    allow: frozenset[int] | None
    deny: frozenset[int]
    allow_sysid: frozenset[int] | None
    deny_sysid: frozenset[int]
    allow_compid: frozenset[int] | None
    deny_compid: frozenset[int]

    @classmethod
    def of(cls, f: FrameFilter) -> CompiledFilter:
        def opt(items: list[Any], conv: Any) -> frozenset[int] | None:
            return frozenset(conv(i) for i in items) if items else None

        return cls(
            opt(f.allow, message_of), frozenset(message_of(i) for i in f.deny),
            opt(f.allow_sysid, int), frozenset(f.deny_sysid),
            opt(f.allow_compid, int), frozenset(f.deny_compid),
        )  # fmt: skip

    def verdict(self, msgid: int, sysid: int, compid: int) -> str | None:
        """``None`` when the frame passes, else the name of the rule that drops it."""
        if self.allow is not None and msgid not in self.allow:
            return "allow"
        if msgid in self.deny:
            return "deny"
        if self.allow_sysid is not None and sysid not in self.allow_sysid:
            return "allow_sysid"
        if sysid in self.deny_sysid:
            return "deny_sysid"
        if self.allow_compid is not None and compid not in self.allow_compid:
            return "allow_compid"
        if compid in self.deny_compid:
            return "deny_compid"
        return None


class EndpointGate:
    """An endpoint's rules, ready for the hot path; ``dropped`` counts drops as ``"down.deny"`` etc."""

    __slots__ = ("_down", "_up", "dropped", "listen_only", "listen_only_sent", "rules")

    def __init__(self, rules: EndpointRules = NO_RULES) -> None:
        self.dropped: Counter[str] = Counter()
        self.listen_only_sent: Counter[str] = Counter()  # message name -> frames a listen-only endpoint sent
        self.rules = rules
        self.listen_only = False
        self._down: CompiledFilter | None = None
        self._up: CompiledFilter | None = None
        self.replace(rules)

    def replace(self, rules: EndpointRules) -> None:
        """Swap the rules (one assignment each; the loop runs one datagram at a time, so never half-applied)."""
        self.rules = rules
        self.listen_only = rules.listen_only
        self._down = None if rules.down.empty else CompiledFilter.of(rules.down)
        self._up = None if rules.up.empty else CompiledFilter.of(rules.up)

    def filters(self, direction: Direction) -> bool:
        return (self._down if direction is Direction.DOWNLINK else self._up) is not None

    def apply(self, data: bytes, direction: Direction) -> bytes:
        """What of ``data`` may go on in ``direction`` (``b""``: nothing)."""
        flt = self._down if direction is Direction.DOWNLINK else self._up
        if flt is None:
            return data
        split = frames.split(data)
        if len(split.frames) == 1 and not split.bad:  # the usual datagram: one frame
            header = split.frames[0][0]
            why = flt.verdict(header.msgid, header.sysid, header.compid)
            if why is None:
                return data
            self.dropped[f"{RULE_SIDE[direction]}.{why}"] += 1
            return b""
        kept: list[bytes] = []
        for header, frame in split.frames:
            why = flt.verdict(header.msgid, header.sysid, header.compid)
            if why is None:
                kept.append(frame)
            else:
                self.dropped[f"{RULE_SIDE[direction]}.{why}"] += 1
        if len(kept) == len(split.frames) and split.clean:
            return data
        return b"".join(kept)

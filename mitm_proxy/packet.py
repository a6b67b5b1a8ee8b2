"""The unit that moves through the proxy's pipeline, and the shape of a stage.

This module is the contract between the frame layer (``frames``, ``codec``),
the pipeline (``pipeline``), the stages (``attack``, ``secure``, tap/record)
and the asyncio edges. It holds no logic beyond the two types.

A :class:`Packet` is one MAVLink frame as it arrived (``raw``), its peeked
header, and what the stages did to it. Stages never touch ``raw``: a stage that
changes a message decodes it into ``fields`` (wire units, as pymavlink decodes),
edits them and sets ``changed``; the pipeline then re-packs the frame with the
original sysid, compid and sequence number. A packet nobody changed leaves as
``raw``, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from attack_profiles.action import Direction

__all__ = ["Direction", "Header", "Packet", "Stage"]


@dataclass(frozen=True, slots=True)
class Header:
    """What can be read from a frame without decoding its payload."""

    version: int  # 1 or 2
    msgid: int
    sysid: int
    compid: int
    seq: int
    payload_len: int
    incompat_flags: int = 0  # v2 only
    signed: bool = False  # v2 with MAVLINK_IFLAG_SIGNED


@dataclass(slots=True)
class Packet:
    """One frame in flight through one link's pipeline."""

    raw: bytes  # the frame exactly as received (or as built, for injected frames)
    header: Header
    direction: Direction
    link: int  # index of the link (vehicle i of the port plan)
    rx_s: float  # monotonic time the datagram arrived
    fields: dict[str, Any] | None = None  # decoded payload, wire units; None until a stage decodes
    changed: bool = False  # True: re-pack from ``fields`` on the way out
    injected: bool = False  # built by a stage, not received
    release_s: float = 0.0  # monotonic time before which it must not be sent (delay)
    notes: list[str] = field(default_factory=list)  # who changed it and why, for the record index


class Stage(Protocol):
    """One step of the pipeline (tap, attack, secure).

    ``active`` False is the seed's bypass: the pipeline skips the stage.
    ``message_ids`` is the set of message ids the stage wants; the pipeline
    hands it nothing else, so untargeted traffic costs one set lookup.
    ``process`` returns the packets to pass on: ``[]`` drops, ``[pkt]`` passes
    (changed or not), extra packets are injected after it.
    """

    name: str

    @property
    def active(self) -> bool: ...

    @property
    def message_ids(self) -> frozenset[int]: ...

    def process(self, pkt: Packet, now_s: float) -> list[Packet]: ...

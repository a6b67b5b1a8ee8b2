"""One MAVLink frame with what was peeked from it, and the direction it travels.

The types every user of the frame layer shares: :func:`mavframe.frames.split`
gives a :class:`Header` per frame, :mod:`mavframe.codec` decodes and re-packs a
:class:`Packet`, and the proxy's pipeline moves packets through its stages.
It holds no logic beyond the types.

A :class:`Packet` is one MAVLink frame as it arrived (``raw``), its peeked
header, and what the stages did to it. Stages never touch ``raw``: a stage that
changes a message decodes it into ``fields`` (wire units, as pymavlink decodes),
edits them and sets ``changed``; the pipeline then re-packs the frame with the
original sysid, compid and sequence number. A packet nobody changed leaves as
``raw``, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

__all__ = ["Direction", "Header", "Packet"]


class Direction(StrEnum):
    """DOWNLINK: vehicle -> ground (telemetry). UPLINK: ground -> vehicle (commands)."""

    DOWNLINK = "downlink"
    UPLINK = "uplink"


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
    origin: str = ""  # for an injected packet, what made it: "inject", "duplicate", "replay" (counted apart)
    release_s: float = 0.0  # monotonic time before which it must not be sent (delay)
    notes: list[str] = field(default_factory=list)  # who changed it and why, for the record index
    # Set by a stage that offers ``memo_fields``: until this monotonic time, the pipeline lets the fast route
    # repeat what the stage did to this frame for frames of the same key (None: not to be repeated).
    steady_until_s: float | None = None

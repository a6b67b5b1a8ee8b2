"""Sequence numbers of one direction of one link, kept contiguous while the proxy adds frames.

A MAVLink receiver counts a gap in a source's ``seq`` (per sysid, compid) as lost frames and a
repeated number as a duplicate: a frame forged with a made-up number gives the attack away in
every ground station's link-quality figure. So a frame the proxy adds (an injection, a duplicate,
a replayed frame) takes the next number of the source it impersonates, and from then on every
real frame of that source leaves with its own number plus the count of frames added so far
(mod 256), with a fresh CRC. In such a direction a real frame a stage drops gives its number back
too, so the receiver sees neither the addition nor the removal. Frames of sources the proxy neither
added to nor dropped from are not touched (in a direction nobody forges in, a drop shows as a gap,
as a lost frame would).

Watching costs one dict write per frame, so it is on only for a direction the proxy forges in
(:attr:`Sequencer.watching`); the pipeline keeps no sequencer at all for a direction nobody forges
in, and its fast path then pays one truth test per datagram.
"""

from __future__ import annotations

from collections.abc import Sequence

from mavframe.packet import Header

__all__ = ["MAX_SOURCES", "Sequencer"]

Key = tuple[int, int]  # (sysid, compid)
MAX_SOURCES = 1024  # sources remembered; sysids come off the wire, so bound what they can make us keep


class Sequencer:
    """Per source: the last number that left, and what real frames gain (see the module doc)."""

    __slots__ = ("align", "last", "offset")

    def __init__(self) -> None:
        self.last: dict[Key, int] = {}  # source -> the seq of the last frame of it that left
        self.offset: dict[Key, int] = {}  # sources the proxy added frames to -> what their real frames gain
        self.align: set[Key] = set()  # forged before any real frame was seen: the first real one sets the offset

    def observe(self, frames: Sequence[tuple[Header, bytes]]) -> bool:
        """The fast path, while watching: note each frame's number; True if one must be renumbered."""
        last, offset = self.last, self.offset
        for h, _ in frames:
            key = (h.sysid, h.compid)
            if key in offset:
                return True  # the slow path renumbers (and notes) every frame of the datagram
            if key in last or len(last) < MAX_SOURCES:
                last[key] = h.seq
        return False

    def real(self, h: Header) -> int:
        """The number a real frame leaves with (its own unless the proxy added frames to its source)."""
        key = (h.sysid, h.compid)
        off = self.offset.get(key)
        if off is None:
            if key in self.last or len(self.last) < MAX_SOURCES:
                self.last[key] = h.seq
            return h.seq
        if key in self.align:
            self.align.discard(key)
            off = self.offset[key] = (self.last[key] + 1 - h.seq) & 0xFF
        out = (h.seq + off) & 0xFF
        self.last[key] = out
        return out

    def dropped(self, h: Header) -> None:
        """A stage dropped a real frame: its source's later frames move down one, so no gap shows."""
        key = (h.sysid, h.compid)
        if key in self.align or (key not in self.offset and len(self.offset) >= MAX_SOURCES):
            return
        self.offset[key] = (self.offset.get(key, 0) - 1) & 0xFF

    def forged(self, sysid: int, compid: int, own: int) -> int:
        """The number of a frame the proxy adds as (sysid, compid); ``own`` is kept when none can be given."""
        key = (sysid, compid)
        if key not in self.offset and len(self.offset) >= MAX_SOURCES:
            return own
        prev = self.last.get(key)
        if prev is None:  # nothing of this source seen yet: start at 0, its real frames will follow on
            out = 0
            self.align.add(key)
            self.offset.setdefault(key, 0)
        else:
            out = (prev + 1) & 0xFF
            self.offset[key] = (self.offset.get(key, 0) + 1) & 0xFF
        self.last[key] = out
        return out

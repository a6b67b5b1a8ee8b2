"""Counters of one link, per direction, and the added latency; published as ``secuav/v<sysid>/stats``.

The pipeline counts what it sees and does; the asyncio edge calls
:meth:`LinkStats.latency` with ``now - rx_s`` when it actually sends a frame.
Latency is kept in a fixed log-spaced histogram (1 µs .. 100 s, ~2 % bins), so
memory stays constant however long the proxy runs and p50/p99 cost one pass
over a few hundred bins.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field
from typing import Any, Final

from mavframe.frames import TEXT
from mavframe.packet import Direction

__all__ = ["DirectionStats", "LatencyHistogram", "LinkStats"]


@dataclass(slots=True)
class DirectionStats:
    """What one direction of one link carried and what the pipeline did to it."""

    frames_in: int = 0
    bytes_in: int = 0
    datagrams_in: int = 0
    frames_out: int = 0
    bytes_out: int = 0
    rewritten: int = 0  # frames re-packed with changed fields
    dropped: int = 0  # valid frames a stage dropped
    injected: int = 0  # frames a stage added (duplicated and replayed ones included)
    duplicated: int = 0  # ... of them, copies of a frame that passed (profile rule ``duplicate``)
    replayed: int = 0  # ... of them, recorded frames played back (profile rule ``frame_replay``)
    delayed: int = 0  # frames held back (release_s in the future)
    unknown: int = 0  # frames of message ids the dialect does not know (forwarded, not CRC-checked)
    signed: int = 0  # signed v2 frames seen
    signed_untouched: int = 0  # signed frames a stage targeted but that were left alone (no key)
    resigned: int = 0  # modified or injected frames signed with the link key
    bad: dict[str, int] = field(default_factory=dict)  # skipped bytes / rejected frames by reason

    def add_bad(self, reason: str, count: int = 1) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + count

    def to_json(self) -> dict[str, Any]:
        return {
            "frames_in": self.frames_in,
            "bytes_in": self.bytes_in,
            "datagrams_in": self.datagrams_in,
            "frames_out": self.frames_out,
            "bytes_out": self.bytes_out,
            "rewritten": self.rewritten,
            "dropped": self.dropped,
            "injected": self.injected,
            "duplicated": self.duplicated,
            "replayed": self.replayed,
            "delayed": self.delayed,
            "unknown": self.unknown,
            "signed": self.signed,
            "signed_untouched": self.signed_untouched,
            "resigned": self.resigned,
            "bad": dict(self.bad),
            # Printable lines (an autopilot's boot text on its serial link) are shown under bad but are not
            # hostile: they stay out of the total that consoles and `secuav-attack status` call "bad".
            "bad_total": sum(n for reason, n in self.bad.items() if reason != TEXT),
        }


class LatencyHistogram:
    """Log-spaced histogram of seconds; O(1) memory, quantiles accurate to one bin (~2 %)."""

    LO_S: Final = 1e-6
    HI_S: Final = 100.0
    BINS_PER_DECADE: Final = 120

    def __init__(self) -> None:
        self._decades = math.log10(self.HI_S / self.LO_S)
        self._n_bins = int(self._decades * self.BINS_PER_DECADE) + 2  # + underflow and overflow
        self._counts = self._empty()
        self.count = 0
        self.max_s = 0.0

    def _empty(self) -> array[int]:
        # An array of C longs, so the compiled fast path (mitm_proxy/net/native_udp.py) counts into it directly.
        return array("q", bytes(8 * self._n_bins))

    def add(self, seconds: float) -> None:
        if seconds != seconds:  # NaN: a caller bug, not a latency
            return
        if seconds <= self.LO_S:
            b = 0
        elif seconds >= self.HI_S:
            b = self._n_bins - 1
        else:
            b = 1 + int(math.log10(seconds / self.LO_S) * self.BINS_PER_DECADE)
        self._counts[b] += 1
        self.count += 1
        if seconds > self.max_s:
            self.max_s = seconds

    def _upper_edge(self, b: int) -> float:
        if b == 0:
            return self.LO_S
        if b == self._n_bins - 1:
            return self.max_s
        return min(self.LO_S * 10 ** (b / self.BINS_PER_DECADE), self.max_s)

    def quantile(self, q: float) -> float | None:
        """The ``q`` quantile (upper bin edge, never above the max seen), or ``None`` when empty."""
        if self.count == 0:
            return None
        rank = max(1, math.ceil(q * self.count))
        seen = 0
        for b, c in enumerate(self._counts):
            seen += c
            if seen >= rank:
                return self._upper_edge(b)
        return self.max_s  # pragma: no cover - rank <= count always reaches a bin

    def reset(self) -> None:
        self._counts = self._empty()
        self.count = 0
        self.max_s = 0.0


class LinkStats:
    """Counters for one link (one vehicle), both directions."""

    def __init__(self, sysid: int | None = None) -> None:
        self.sysid = sysid
        self.directions: dict[Direction, DirectionStats] = {d: DirectionStats() for d in Direction}
        self.latency_hist = LatencyHistogram()

    def __getitem__(self, direction: Direction) -> DirectionStats:
        return self.directions[direction]

    def latency(self, seconds: float) -> None:
        """Record the time one frame spent in the proxy (send time minus ``Packet.rx_s``)."""
        self.latency_hist.add(seconds)

    def snapshot(self) -> dict[str, Any]:
        """JSON-ready counters: ``{"downlink": {...}, "uplink": {...}, "latency_ms": {...}}``."""
        h = self.latency_hist
        p50, p99 = h.quantile(0.5), h.quantile(0.99)
        out: dict[str, Any] = {d.value: s.to_json() for d, s in self.directions.items()}
        out["latency_ms"] = {
            "count": h.count,
            "p50": None if p50 is None else p50 * 1e3,
            "p99": None if p99 is None else p99 * 1e3,
            "max": h.max_s * 1e3 if h.count else None,
        }
        if self.sysid is not None:
            out["sysid"] = self.sysid
        return out

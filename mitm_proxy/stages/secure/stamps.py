"""When a reading was taken, on the proxy's clock: the sender's ``time_boot_ms`` mapped onto it.

A reading's arrival is not when it was taken: the link delays it, an autopilot or a router batches several
readings into one datagram, a replay delivers it late. Timing each reading by its arrival hands the asynchronous
estimators (estimators/aligned.py) a vehicle that looks where it was one delay ago. The sender stamps every
DISTANCE_SENSOR with its own clock (``time_boot_ms``); this module maps that stamp onto the proxy's monotonic
clock, one mapping per source (system id, component id: each has its own boot):

    t_read = stamp + min over the readings stamped in the last ``window_s`` of (arrival - stamp),  never after arrival

The smallest offset seen is the link's least delay (the minimum filter of one-way delay measurements: V. Paxson,
"On calibrating measurements of packet transit times", ACM SIGMETRICS 1998; NTP's clock filter likewise trusts its
least-delay sample, D. L. Mills, RFC 5905): a delayed reading has a larger offset and cannot lower it, so a delay
only ever makes readings look older, never newer, and a reading is never mapped after its own arrival (it is in the
window).
Under jitter in ``[d0, d0 + J]`` every reading is placed within ``J`` of its true time plus the unobservable
constant ``d0``, the same for all of a source's readings (``d0`` shifts everything alike, so a moving vehicle's
estimate lags by ``d0``, as it does with no jitter at all); after one reading of least delay in the window, within
the ``d0`` of that reading. The window runs on the sender's stamps, not on arrivals, so an outage does not empty
it: readings held back and delivered in one burst (a router, an autopilot batching, a link that stalled) are
placed at their stamps as long as the burst reaches back no more than ``window_s`` (2 s) before its newest
reading; past that, the later part of the burst is placed at its arrival, as without stamps. The window forgets
so that a clock drifting against the proxy's (a simulator behind real time) makes readings look older by at most
the drift over ``window_s`` (1 % of 2 s: 20 ms).

Re-anchoring (log ``secure.clock_anchor`` with ``reason``, at most one line a second per sender, the next line
counting those left out in ``unlogged``; counted in the stats): the mapping starts again from readings that show a
reboot or a time jump. A reading whose stamp does not fit the sender's clock,

- ``stamp_backwards``: a stamp more than ``jump_s`` before the source's newest (a reboot; a replayed frame); a
  reading a little out of order is not one;
- ``stamp_ahead``: an offset more than ``jump_s`` below the smallest (the sender's clock jumped forward),

is timed at its arrival and counted (``off_clock``); once ``CONFIRM`` (3) such readings in a row agree on a new
offset (within ``jump_s``), the mapping moves to it. A reading that fits the clock in between ends the run: a
replayed frame among the vehicle's own moves nothing (it is timed at arrival, the vehicle's readings keep their
stamps). Runs of replayed frames do take the clock while they last, and the vehicle's readings are then timed at
their arrival: no worse than ``reading_time: arrival``, never newer than their arrival, and loud in the counters.

- ``stamp_behind``: every reading for ``jump_s`` of arrivals more than ``jump_s`` above the smallest offset (the
  sender's clock stopped or was set back while it kept sending, a simulator paused and resumed) re-anchors at
  once: those readings were placeable, only too old. A burst after an outage is not one: its late readings arrive
  together and the next on-time reading ends it.

A reading without a usable stamp (``time_boot_ms`` absent or 0, as some companions send) is timed at its arrival and
counted (``unstamped``). ``reading_time: arrival`` in the stage's configuration times every reading at its arrival,
as before this module. Whatever the stamps, an attacker who replays or delays frames cannot make a reading look
newer than its arrival.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Literal

log = logging.getLogger(__name__)

ReadingTime = Literal["stamp", "arrival"]
Source = tuple[int, int]  # (sysid, compid): one sender's clock
WINDOW_S = 2.0  # the offsets the smallest is taken over
JUMP_S = 0.5  # an offset change or a stamp going back by more than this is a reboot or a jump
CONFIRM = 3  # readings in a row that must agree on a new offset before the mapping moves to it
LOG_EVERY_S = 1.0  # at most one clock_anchor line a second per sender (the others counted in the next)


@dataclass(slots=True)
class _Candidate:
    """A new offset some readings agree on, that the mapping moves to once ``CONFIRM`` of them in a row have."""

    reason: str
    offset_s: float  # the least offset among them
    newest_ms: int
    count: int = 1


@dataclass(slots=True)
class _SourceClock:
    """One sender's mapping: a monotonic deque of (stamp, offset), offsets increasing, for the sliding minimum."""

    lows: deque[tuple[int, float]] = field(default_factory=deque)
    newest_ms: int = 0
    behind_since_s: float | None = None  # arrival since which every reading's offset was far above the smallest
    candidate: _Candidate | None = None  # readings that do not fit: a reboot, a jump, or strays (replayed frames)
    logged_s: float = -math.inf  # the last anchor logged (at most one a second per sender)
    unlogged: int = 0  # anchors since, not logged

    def anchor(self, stamp_ms: int, offset_s: float) -> None:
        self.lows.clear()
        self.lows.append((stamp_ms, offset_s))
        self.newest_ms, self.behind_since_s, self.candidate = stamp_ms, None, None

    @property
    def offset_s(self) -> float:
        return self.lows[0][1]


class StampClock:
    """Maps each reading's sender stamp onto the proxy's clock (module docstring); pure: no clock of its own."""

    def __init__(self, mode: ReadingTime = "stamp", window_s: float = WINDOW_S, jump_s: float = JUMP_S,
                 name: str = "") -> None:  # fmt: skip
        self.mode: ReadingTime = mode
        self.window_s = window_s
        self.jump_s = jump_s
        self.name = name  # for the log line: whose stage
        self.sources: dict[Source, _SourceClock] = {}
        self.stamped = 0  # readings placed by their stamp
        self.unstamped = 0  # readings with no usable stamp, timed at arrival (stamp mode)
        self.off_clock = 0  # readings whose stamp did not fit their sender's clock, timed at arrival
        self.reanchors: dict[str, int] = {}  # by reason, first anchors of a source not counted

    def time_of(self, source: Source, stamp_ms: Any, arrival_s: float) -> float:
        """When the reading stamped ``stamp_ms`` by ``source`` and arriving at ``arrival_s`` was taken."""
        if self.mode == "arrival":
            return arrival_s
        if not isinstance(stamp_ms, int) or isinstance(stamp_ms, bool) or stamp_ms <= 0:
            self.unstamped += 1
            return arrival_s
        offset_s = arrival_s - stamp_ms / 1000.0
        clock = self.sources.get(source)
        if clock is None:
            clock = self.sources[source] = _SourceClock()
            self._anchor(source, clock, stamp_ms, offset_s, arrival_s, "first")
            self.stamped += 1
            return arrival_s
        reason = self._jump(clock, stamp_ms, offset_s, arrival_s)
        if reason == "stamp_behind":  # placeable, but far too old for this long: its clock stopped or went back
            self._anchor(source, clock, stamp_ms, offset_s, arrival_s, reason)
        elif reason is not None:  # not placeable on this clock: a reboot, a jump, or a stray (a replayed frame)
            cand = clock.candidate
            if cand is not None and abs(offset_s - cand.offset_s) <= self.jump_s:
                cand.count += 1
                cand.offset_s, cand.newest_ms = min(cand.offset_s, offset_s), max(cand.newest_ms, stamp_ms)
            else:
                cand = clock.candidate = _Candidate(reason, offset_s, stamp_ms)
            if cand.count < CONFIRM:
                self.off_clock += 1
                return arrival_s
            self._anchor(source, clock, cand.newest_ms, cand.offset_s, arrival_s, cand.reason)
        else:
            clock.candidate = None  # it fits: the readings that did not were strays
        self.stamped += 1
        lows = clock.lows
        while lows and lows[-1][1] >= offset_s:
            lows.pop()
        lows.append((stamp_ms, offset_s))
        clock.newest_ms = max(clock.newest_ms, stamp_ms)
        while len(lows) > 1 and lows[0][0] < clock.newest_ms - self.window_s * 1000.0:
            lows.popleft()  # (this reading stays: it is the last, so never mapped after its arrival)
        return min(arrival_s, stamp_ms / 1000.0 + clock.offset_s)

    def _jump(self, clock: _SourceClock, stamp_ms: int, offset_s: float, arrival_s: float) -> str | None:
        if stamp_ms < clock.newest_ms - self.jump_s * 1000.0:
            return "stamp_backwards"
        least = clock.offset_s
        if offset_s < least - self.jump_s:
            return "stamp_ahead"
        if offset_s <= least + self.jump_s:
            clock.behind_since_s = None
            return None
        if clock.behind_since_s is None:
            clock.behind_since_s = arrival_s
        return "stamp_behind" if arrival_s - clock.behind_since_s >= self.jump_s else None

    def _anchor(self, source: Source, clock: _SourceClock, stamp_ms: int, offset_s: float, arrival_s: float,
                reason: str) -> None:  # fmt: skip
        old = clock.offset_s if clock.lows else None
        clock.anchor(stamp_ms, offset_s)
        if reason != "first":
            self.reanchors[reason] = self.reanchors.get(reason, 0) + 1
        if arrival_s - clock.logged_s < LOG_EVERY_S:
            clock.unlogged += 1
            return
        log.log(logging.INFO if reason == "first" else logging.WARNING, "secure.clock_anchor",
                extra={"stage": self.name, "sysid": source[0], "compid": source[1], "reason": reason,
                       "stamp_ms": stamp_ms, "offset_s": round(offset_s, 6),
                       "previous_offset_s": None if old is None else round(old, 6),
                       "unlogged": clock.unlogged})  # fmt: skip
        clock.logged_s, clock.unlogged = arrival_s, 0

    def stats(self) -> dict[str, Any]:
        """The stage's stats keys (report.stage_stats); safe to call from another thread than the one mapping."""
        reasons = self.reanchors.copy()  # one C call under the GIL: never a dict changing size mid-iteration
        return {
            "reading_time": self.mode,
            "readings_stamped": self.stamped,
            "readings_unstamped": self.unstamped,
            "readings_off_clock": self.off_clock,
            "clock_sources": len(self.sources),
            "clock_reanchors": sum(reasons.values()),
            "clock_reanchor_reasons": dict(sorted(reasons.items())),
        }

"""One vehicle's link: its vehicle endpoint, its ground endpoints and its pipeline.

The link is the thin asyncio edge around the sans-I/O :class:`Pipeline`: it
feeds each datagram in with its arrival time and direction, and sends what
comes out, now or (for frames a stage delayed) at ``release_s`` with
``loop.call_at``. Added latency is recorded when a frame actually leaves
(:meth:`LinkStats.latency`), for frames sent at once (a delay a profile asked
for is the attack, not the proxy's cost).

Routing (decided here, following MAVLink's routing rules as mavlink-router and
the autopilots apply them):

- downlink: every frame of vehicle i goes to every ground endpoint of link i;
- uplink from an endpoint that only link i uses goes to vehicle i, untouched;
- uplink from an endpoint shared by several links (the GCS port 14550 carries
  all vehicles) goes, frame by frame, to the link whose sysid is the frame's
  ``target_system``; a frame without one, with ``target_system`` 0 (broadcast)
  or with a system no link has goes to every link. A datagram whose frames all
  go everywhere is passed on whole, byte for byte.
- ground endpoints do not hear each other (a GCS never sees MAVSDK's commands).

If the pipeline raises (a bug, never bad input: bad input is counted inside),
the datagram is forwarded as it came and the error logged once: the proxy
fails open, so a vehicle never loses its link because of us.

Frames on a clock (an injection, a replayed recording): the link arms one timer at
:meth:`Pipeline.next_tick_s` and, when it fires, sends what :meth:`Pipeline.tick` returns
(uplink to the vehicle, downlink to every ground endpoint), then arms the next. With nothing
scheduled there is no timer; a stage says when that may have changed through its
``on_schedule`` hook, which the link sets to :meth:`Link.wake`.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Sequence

from mavframe import frames
from mavframe.layout import target_system
from mavframe.packet import Direction
from mitm_proxy.core.pipeline import Outgoing, Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.net.endpoints import BaseEndpoint

log = logging.getLogger(__name__)


class Link:
    """Vehicle i of the process: ``from_vehicle`` / ``from_ground`` are the endpoints' receivers."""

    def __init__(
        self,
        index: int,
        sysid: int,
        pipeline: Pipeline,
        stats: LinkStats,
        vehicle: BaseEndpoint,
        grounds: Sequence[BaseEndpoint],
    ) -> None:
        self.index = index
        self.sysid = sysid
        self.pipeline = pipeline
        self.stats = stats
        self.vehicle = vehicle
        self.grounds = list(grounds)
        self.pipeline_errors = 0
        self.pending = 0  # delayed frames not yet sent
        self._loop = asyncio.get_running_loop()
        self._handles: set[asyncio.TimerHandle] = set()
        self._tick: asyncio.TimerHandle | None = None
        self._tick_at: float | None = None  # monotonic time the armed tick is for
        self.tick_errors = 0
        vehicle.receiver = self.from_vehicle
        bind = getattr(vehicle, "bind_fast", None)  # the compiled fast path (net/native_udp.py) forwards for us
        if bind is not None:
            bind(vehicle.receiver, self, Direction.DOWNLINK, self.grounds)
        for stage in pipeline.stages:
            if hasattr(stage, "on_schedule"):
                stage.on_schedule = self.wake  # type: ignore[attr-defined]
        self.wake()

    def from_vehicle(self, data: bytes, rx_s: float) -> None:
        self._feed(data, Direction.DOWNLINK, rx_s, self.grounds)

    def from_ground(self, data: bytes, rx_s: float) -> None:
        self._feed(data, Direction.UPLINK, rx_s, (self.vehicle,))

    def _feed(self, data: bytes, direction: Direction, rx_s: float, targets: Sequence[BaseEndpoint]) -> None:
        try:
            outs = self.pipeline.feed(data, direction, rx_s)
        except Exception:
            self.pipeline_errors += 1
            if self.pipeline_errors == 1:
                log.exception("link.pipeline_error", extra={"sysid": self.sysid, "direction": str(direction)})
            outs = [Outgoing(data, 0.0, rx_s)]
        now = time.monotonic()
        for out in outs:
            if out.release_s > now:
                self._schedule(out, targets, now)
                continue
            for ep in targets:
                ep.send(out.data)
            self.stats.latency(time.monotonic() - (out.rx_s or rx_s))

    def _schedule(self, out: Outgoing, targets: Sequence[BaseEndpoint], now: float) -> None:
        handle: asyncio.TimerHandle | None = None

        def fire() -> None:
            self.pending -= 1
            if handle is not None:
                self._handles.discard(handle)
            for ep in targets:
                ep.send(out.data)

        handle = self._loop.call_at(self._loop.time() + (out.release_s - now), fire)
        self._handles.add(handle)
        self.pending += 1

    def wake(self) -> None:
        """(Re)arm the tick timer for the pipeline's next due frame; nothing due: no timer."""
        try:
            at = self.pipeline.next_tick_s()
        except Exception:  # a stage bug: no clock-driven frames, forwarding goes on
            at = None
            self.tick_errors += 1
            if self.tick_errors == 1:
                log.exception("link.tick_error", extra={"sysid": self.sysid})
        if self._tick is not None:
            if at is not None and at == self._tick_at:
                return
            self._tick.cancel()
            self._tick = self._tick_at = None
        if at is None:
            return
        self._tick_at = at
        self._tick = self._loop.call_at(self._loop.time() + max(0.0, at - time.monotonic()), self._on_tick)

    def _on_tick(self) -> None:
        self._tick = self._tick_at = None
        now = time.monotonic()
        try:
            outs = self.pipeline.tick(now)
        except Exception:
            outs = []
            self.tick_errors += 1
            if self.tick_errors == 1:
                log.exception("link.tick_error", extra={"sysid": self.sysid})
        for direction, out in outs:
            for ep in self.grounds if direction is Direction.DOWNLINK else (self.vehicle,):
                ep.send(out.data)
        self.wake()

    def close(self) -> None:
        """Cancel frames still held back (they are counted as delayed, never sent), and the tick timer."""
        for handle in self._handles:
            handle.cancel()
        self._handles.clear()
        self.pending = 0
        if self._tick is not None:
            self._tick.cancel()
            self._tick = self._tick_at = None
        for stage in self.pipeline.stages:
            if getattr(stage, "on_schedule", None) == self.wake:
                stage.on_schedule = None  # type: ignore[attr-defined]


class GroundRouter:
    """The receiver of one ground endpoint: hands uplink to the link(s) it belongs to (see module doc)."""

    def __init__(self, endpoint: BaseEndpoint, links: Sequence[Link]) -> None:
        self.endpoint = endpoint
        self.links = list(links)
        self._by_sysid = {ln.sysid: ln for ln in self.links}
        endpoint.receiver = self.links[0].from_ground if len(self.links) == 1 else self.route
        bind = getattr(endpoint, "bind_fast", None)
        if bind is not None and len(self.links) == 1:  # a shared endpoint routes frame by frame: Python's job
            bind(endpoint.receiver, self.links[0], Direction.UPLINK, (self.links[0].vehicle,))

    def route(self, data: bytes, rx_s: float) -> None:
        split = frames.split(data)
        per_link: dict[int, list[bytes]] = {}
        everywhere = True
        for header, frame in split.frames:
            link = self._by_sysid.get(target_system(header, frame))
            if link is None:
                for ln in self.links:
                    per_link.setdefault(ln.sysid, []).append(frame)
            else:
                everywhere = False
                per_link.setdefault(link.sysid, []).append(frame)
        if everywhere:  # nothing addressed to one vehicle: the datagram as it came (bad bytes included)
            for ln in self.links:
                ln.from_ground(data, rx_s)
            return
        for ln in self.links:
            chunk = per_link.get(ln.sysid)
            if chunk:
                ln.from_ground(b"".join(chunk), rx_s)

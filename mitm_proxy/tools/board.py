"""What a ``secuav-attack`` session has seen on the broker: the latest message per topic, checked against its
model, and the requests waiting for their acknowledgement. ``status`` reads it once, ``status --watch``
(:mod:`mitm_proxy.tools.watch`) redraws it.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from secuav_common.controlplane.payloads import PayloadError, as_dict, decode
from secuav_common.controlplane.requests import Acks
from secuav_common.controlplane.topics import parse

SETTLE_S = 0.3  # retained messages follow the SUBACK at once; this long without one means we have them all


def _leaf(leaf: str, verb: str | None) -> str:
    return f"{leaf}/{verb}" if verb else leaf


@dataclass
class Board:
    """Everything seen on the subscribed topics, latest per topic, and who is waiting for what."""

    latest: dict[str, Any] = field(default_factory=dict)
    arrivals: dict[str, float] = field(default_factory=dict)  # topic -> monotonic time of its latest message
    last_arrival_s: float = field(default_factory=time.monotonic)
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    acks: Acks = field(default_factory=Acks)
    refused: int = 0  # messages that did not fit their topic's model (skipped)

    def receive(self, topic: str, raw: bytes) -> None:
        """One message from the broker: checked against its topic's model, kept as plain JSON."""
        try:
            body = as_dict(decode(topic, raw))
        except PayloadError:
            self.refused += 1
            return
        self.latest[topic] = body
        self.last_arrival_s = self.arrivals[topic] = time.monotonic()
        self.acks.feed(topic, body)
        self.changed.set()

    def vehicles(self, leaf: str = "attack/state") -> list[int]:
        found = set()
        for topic in self.latest:
            parsed = parse(topic)
            if parsed is not None and parsed.sysid is not None and _leaf(parsed.leaf, parsed.verb) == leaf:
                found.add(parsed.sysid)
        return sorted(found)

    def instances(self) -> dict[str, dict[str, Any]]:
        """Proxy instance -> its online record (``secuav/proxy/<instance>/online``)."""
        return self.by_instance("online", None)

    def by_instance(self, leaf: str, verb: str | None) -> dict[str, dict[str, Any]]:
        found = {}
        for topic, body in self.latest.items():
            parsed = parse(topic)
            if (parsed is not None and parsed.scope == "proxy" and parsed.key is not None and parsed.leaf == leaf
                    and parsed.verb == verb and isinstance(body, dict)):  # fmt: skip
                found[parsed.key] = body
        return dict(sorted(found.items()))

    def online_instances(self) -> list[str]:
        return [name for name, rec in self.instances().items() if rec.get("online") is True]

    async def settle(self, limit_s: float) -> None:
        """Wait until no message came for :data:`SETTLE_S` (the retained ones are in) or ``limit_s`` passed."""
        deadline = time.monotonic() + limit_s
        while (now := time.monotonic()) < deadline:
            quiet_s = now - self.last_arrival_s
            if quiet_s >= SETTLE_S:
                return
            await asyncio.sleep(min(SETTLE_S - quiet_s, deadline - now))

    async def until(self, done: Callable[[], bool], limit_s: float) -> bool:
        deadline = time.monotonic() + limit_s
        while not done():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.changed.clear()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self.changed.wait(), remaining)
        return True



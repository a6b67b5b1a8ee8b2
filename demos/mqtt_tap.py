"""The demo's view of the control plane: record topics, push a profile and wait for its acknowledgement."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import PayloadError, validate
from secuav_common.controlplane.requests import Acks
from secuav_common.controlplane.session import Client, MqttError, Session, messages


@dataclass
class Sample:
    wall_s: float  # time.time() on arrival
    topic: str
    payload: Any


@dataclass
class Tap:
    """Subscribes to ``topics`` and keeps every message that fits its topic's model, with its arrival time."""

    host: str
    port: int
    topics: list[str]
    samples: list[Sample] = field(default_factory=list)
    refused: int = 0  # messages that did not fit their topic's model (skipped)
    _client: Client | None = None
    _task: asyncio.Task[None] | None = None
    _ready: asyncio.Event = field(default_factory=asyncio.Event)
    _acks: Acks = field(default_factory=Acks)

    async def __aenter__(self) -> Tap:
        self._task = asyncio.create_task(self._run())
        await asyncio.wait_for(self._ready.wait(), 10.0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, MqttError):
                await self._task

    async def _run(self) -> None:
        session = Session(BrokerAddress(self.host, self.port), identifier=f"secuav-demo-{uuid.uuid4().hex[:8]}")
        async with session.client() as client:
            self._client = client
            for topic in self.topics:
                await client.subscribe(topic)
            self._ready.set()
            async for topic, raw, _retained in messages(client):
                try:
                    payload = json.loads(raw)
                    validate(topic, payload)
                except (ValueError, TypeError, PayloadError):
                    self.refused += 1
                    continue
                self.samples.append(Sample(time.time(), topic, payload))
                self._acks.feed(topic, payload)

    def on(self, topic: str) -> list[Sample]:
        return [s for s in self.samples if s.topic == topic]

    async def request(self, topic: str, payload: Any, timeout_s: float = 10.0) -> dict[str, Any]:
        """Publish ``payload`` (``None`` clears) with a fresh ``request_id`` on a ``.../set`` topic and return the
        state that acknowledges it (the tap must be subscribed to that state); ``TimeoutError`` if none came."""
        assert self._client is not None
        (state,) = await self._acks.request_all(self._client, [(topic, payload)], timeout_s)
        if state is None:
            raise TimeoutError(f"no acknowledgement for {topic} within {timeout_s:.0f} s")
        return state

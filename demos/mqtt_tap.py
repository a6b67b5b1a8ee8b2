"""The demo's view of the control plane: record topics, push a profile and wait for its acknowledgement."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import aiomqtt


@dataclass
class Sample:
    wall_s: float  # time.time() on arrival
    topic: str
    payload: Any


@dataclass
class Tap:
    """Subscribes to ``topics`` and keeps every JSON message with its arrival time."""

    host: str
    port: int
    topics: list[str]
    samples: list[Sample] = field(default_factory=list)
    _client: aiomqtt.Client | None = None
    _task: asyncio.Task[None] | None = None
    _ready: asyncio.Event = field(default_factory=asyncio.Event)

    async def __aenter__(self) -> Tap:
        self._task = asyncio.create_task(self._run())
        await asyncio.wait_for(self._ready.wait(), 10.0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await self._task

    async def _run(self) -> None:
        async with aiomqtt.Client(self.host, self.port, identifier=f"secuav-demo-{uuid.uuid4().hex[:8]}") as client:
            self._client = client
            for topic in self.topics:
                await client.subscribe(topic)
            self._ready.set()
            async for message in client.messages:
                try:
                    payload = json.loads(bytes(message.payload))  # type: ignore[arg-type]
                except (ValueError, TypeError):
                    continue
                self.samples.append(Sample(time.time(), str(message.topic), payload))

    def on(self, topic: str) -> list[Sample]:
        return [s for s in self.samples if s.topic == topic]

    async def request(self, topic: str, payload: Any, state_topic: str, timeout_s: float = 10.0) -> dict[str, Any]:
        """Publish ``payload`` with a fresh ``request_id`` and return the state that acknowledges it."""
        assert self._client is not None
        request_id = uuid.uuid4().hex
        body = {**payload, "request_id": request_id} if isinstance(payload, dict) else {"request_id": request_id}
        if payload is None:
            body = {"request_id": request_id}  # an empty set request clears
        start = len(self.samples)
        await self._client.publish(topic, json.dumps(body), qos=1)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for s in self.samples[start:]:
                if s.topic == state_topic and isinstance(s.payload, dict) and s.payload.get("request_id") == request_id:
                    return s.payload
            await asyncio.sleep(0.05)
        raise TimeoutError(f"no acknowledgement on {state_topic} for request {request_id} within {timeout_s:.0f} s")

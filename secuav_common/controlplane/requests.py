"""Request and acknowledgement: publish a ``.../set`` with a fresh ``request_id``, wait for the ``.../state``
that carries it.

The proxy answers every request on the retained state topic next to it, with
the request's id, ``ok`` and ``error``: the proxy's own verdict, not just the
broker's receipt. :class:`Acks` is fed every message the caller's session
receives (:meth:`Acks.feed`) and resolves whoever waits for that id; the
caller must be subscribed to the state topics it expects answers on.
"""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import Sequence
from typing import Any

import aiomqtt

from secuav_common.controlplane.payloads import request_bytes
from secuav_common.controlplane.topics import parse


class AckTimeout(Exception):
    """No acknowledgement from the proxy in time."""


class Acks:
    """Requests waiting for their acknowledgement, by request id."""

    def __init__(self, prefix: str = "") -> None:
        self.prefix = prefix  # request ids say who asked (``console-...``)
        self._waiting: dict[str, asyncio.Future[dict[str, Any]]] = {}

    def new_id(self) -> str:
        return f"{self.prefix}{uuid.uuid4().hex}"

    def feed(self, topic: str, body: Any) -> None:
        """One received message: a state carrying a request id someone waits for resolves that wait."""
        if not (isinstance(body, dict) and isinstance(rid := body.get("request_id"), str)):
            return
        waiter = self._waiting.get(rid)
        if waiter is None or waiter.done():
            return
        parsed = parse(topic)
        if parsed is not None and parsed.verb == "state":
            waiter.set_result(body)

    async def request_all(
        self, client: aiomqtt.Client, requests: Sequence[tuple[str, Any]], timeout_s: float
    ) -> list[dict[str, Any] | None]:
        """Send every ``(set topic, body)`` (``body`` None: a bare request, e.g. "clear"), then wait up to
        ``timeout_s`` for all answers; each is the proxy's state, or ``None`` if it did not come."""
        loop = asyncio.get_running_loop()
        ids = [self.new_id() for _ in requests]
        futures = [loop.create_future() for _ in requests]
        self._waiting.update(zip(ids, futures, strict=True))
        try:
            for (topic, body), rid in zip(requests, ids, strict=True):
                await client.publish(topic, request_bytes(body, rid), qos=1)
            await asyncio.wait(futures, timeout=timeout_s)
            return [f.result() if f.done() and not f.cancelled() else None for f in futures]
        finally:
            for rid in ids:
                self._waiting.pop(rid, None)

    async def request(self, client: aiomqtt.Client, topic: str, body: Any, timeout_s: float) -> dict[str, Any]:
        """Send one request; the proxy's state for it, or :class:`AckTimeout` naming the state topic."""
        (state,) = await self.request_all(client, [(topic, body)], timeout_s)
        if state is None:
            parsed = parse(topic)
            where = parsed.with_verb("state") if parsed is not None else topic
            raise AckTimeout(f"no acknowledgement on {where} within {timeout_s:g} s")
        return state

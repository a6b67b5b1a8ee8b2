"""The embedded amqtt broker with a packet size limit: a packet that declares more is never read.

amqtt has no size limit of its own: it reads a PUBLISH of any size into memory,
keeps it if retained, and hands it to every subscriber (the hostile review's
30 MB retained message made every proxy hold it). Here each connection's
reader follows the MQTT framing (type byte, remaining length, body) as amqtt
reads it; when a fixed header declares more than ``limit`` bytes the
connection is cut before the body is read, and that is logged once per 10 s
with the count. Used by :class:`secuav_common.broker.EmbeddedBroker` and
:mod:`secuav_common.broker_main` (the only places that import amqtt's broker).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from amqtt.adapters import ReaderAdapter, StreamReaderAdapter, StreamWriterAdapter
from amqtt.broker import Broker

from secuav_common.controlplane.payloads import MAX_PACKET_BYTES
from secuav_common.logs import RateLimitedLog

log = logging.getLogger("secuav_common.broker")
refusals = RateLimitedLog(log)


class CappedReader(ReaderAdapter):
    """amqtt's stream reader, following the packet framing and cutting the connection at an oversized one."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, limit: int) -> None:
        self._inner = StreamReaderAdapter(reader)
        self._writer = writer
        self.limit = limit
        self._left = 0  # body bytes of the current packet still to come
        self._in_length = False  # reading the remaining-length bytes
        self._length = 0
        self._shift = 0

    async def read(self, n: int = -1) -> bytes:
        data = await self._inner.read(n)
        self._follow(data)
        return data

    def _follow(self, data: bytes) -> None:
        i, n = 0, len(data)
        while i < n:
            if self._left:  # body: skip what it covers at once
                step = min(self._left, n - i)
                self._left -= step
                i += step
            elif not self._in_length:  # the type byte
                self._in_length, self._length, self._shift = True, 0, 0
                i += 1
            else:
                byte = data[i]
                i += 1
                self._length |= (byte & 0x7F) << self._shift
                self._shift += 7
                if byte & 0x80 and self._shift < 28:
                    continue
                self._in_length = False
                if self._length > self.limit:
                    self._refuse(self._length)
                self._left = self._length

    def _refuse(self, size: int) -> None:
        peer = self._writer.get_extra_info("peername")
        refusals.event("broker.packet_too_large", client=f"{peer[0]}:{peer[1]}" if peer else "?", bytes=size,
                       limit=self.limit)  # fmt: skip
        self._writer.transport.abort()
        # amqtt turns a reset into "no more data" and closes the session, unread.
        raise ConnectionResetError(f"packet of {size} bytes is larger than {self.limit} bytes")

    def feed_eof(self) -> None:
        self._inner.feed_eof()


class SnapshotDict(dict[str, Any]):
    """A dict whose iteration walks a copy of its keys (items), so a loop that awaits inside it survives
    another task adding or removing a key meanwhile.

    amqtt 0.12 loops over its subscription table with awaits in the body (publishing retained messages to a
    new session, broadcasting); a client subscribing to a new topic during that loop raised "dictionary
    changed size during iteration" and ended the other client's session (seen once in a parallel test run)."""

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(list(super().keys()))

    def items(self):  # type: ignore[no-untyped-def, override]
        return list(super().items())


class CappedBroker(Broker):
    """amqtt's broker, each TCP connection read through :class:`CappedReader`; its subscription table is a
    :class:`SnapshotDict`."""

    def __init__(self, config: dict[str, Any], limit: int = MAX_PACKET_BYTES) -> None:
        super().__init__(config)
        self.packet_limit = limit
        self._subscriptions = SnapshotDict(self._subscriptions)

    async def stream_connected(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                               listener_name: str) -> None:  # fmt: skip
        await self.external_connected(CappedReader(reader, writer, self.packet_limit), StreamWriterAdapter(writer),
                                      listener_name)  # fmt: skip

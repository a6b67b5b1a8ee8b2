"""``tcpin://HOST:PORT``: the vehicle serves MAVLink on TCP, as ArduPilot and PX4 SITL do on 5760.

Every client that connects gets the vehicle's stream and may command it. The
byte stream is cut back into whole frames (:class:`mavframe.frames.StreamFramer`)
before the vehicle's datagram decoder sees it, so a frame split across two TCP
segments is not lost. A client that stops reading is dropped once more than
``MAX_BUFFERED`` bytes wait for it, rather than holding the simulation back.
Same shape as :class:`flightsim.mavlink.udp.UdpLink`: ``send`` queues, ``flush``
writes once per tick.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from mavframe.frames import StreamFramer
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)
MAX_BUFFERED = 256 * 1024
Address = tuple[str, int]


class _Client(asyncio.Protocol):
    def __init__(self, link: TcpServerLink) -> None:
        self.link = link
        self.framer = StreamFramer()
        self.transport: asyncio.Transport | None = None
        self.peer = "?"

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        peer = transport.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if peer else "?"
        self.link.clients.add(self)
        log.info("tcp.client", extra={"mavlink": str(self.link.endpoint), "peer": self.peer,
                                      "clients": len(self.link.clients)})  # fmt: skip

    def data_received(self, data: bytes) -> None:
        whole = self.framer.feed(data)
        if whole:
            self.link.received(whole)

    def connection_lost(self, exc: Exception | None) -> None:
        self.link.clients.discard(self)
        log.info("tcp.client_gone", extra={"mavlink": str(self.link.endpoint), "peer": self.peer})


class TcpServerLink:
    """A TCP server for one vehicle; see the module doc."""

    def __init__(self, endpoint: Endpoint, on_datagram: Callable[[bytes, float], None]) -> None:
        self.endpoint = endpoint
        self._on_datagram = on_datagram
        self._server: asyncio.Server | None = None
        self.clients: set[_Client] = set()
        self._pending: list[bytes] = []
        self.send_errors = 0
        self.rx_datagrams = 0
        self.tx_datagrams = 0
        self.on_after_receive: Callable[[], None] | None = None

    async def open(self) -> TcpServerLink:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Client(self), self.endpoint.host, self.endpoint.port,
                                                reuse_address=True)  # fmt: skip
        return self

    @property
    def local_address(self) -> Address:
        assert self._server is not None and self._server.sockets
        return self._server.sockets[0].getsockname()[:2]

    def received(self, data: bytes) -> None:
        self.rx_datagrams += 1
        self._on_datagram(data, time.monotonic())
        if self.on_after_receive is not None:
            self.on_after_receive()

    def send(self, frame: bytes) -> None:
        self._pending.append(frame)

    def flush(self) -> None:
        if not self._pending:
            return
        data = b"".join(self._pending)
        self._pending.clear()
        for client in list(self.clients):
            t = client.transport
            if t is None or t.is_closing():
                continue
            if t.get_write_buffer_size() > MAX_BUFFERED:
                self.send_errors += 1
                log.warning("tcp.client_too_slow", extra={"mavlink": str(self.endpoint), "peer": client.peer})
                t.abort()
                continue
            t.write(data)
            self.tx_datagrams += 1

    def close(self) -> None:
        self.flush()
        for client in list(self.clients):
            if client.transport is not None:
                client.transport.close()
        if self._server is not None:
            self._server.close()

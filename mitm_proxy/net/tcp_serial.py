"""Byte-stream endpoints: TCP client and server, serial port.

``tcp://HOST:PORT`` connects to a MAVLink TCP server (ArduPilot SITL serves
5760) and, when the connection fails or drops, tries again with a backoff of
0.25 s doubling to 5 s (reset once a connection has lasted 2 s, so a peer
that accepts and hangs up at once cannot make it spin); the proxy starts
whether or not the server is up yet. ``tcpin://HOST:PORT`` listens: every client that
connects is a peer (a spectator GCS, a script), each gets everything sent to
the endpoint and anything each sends is handed on. ``serial:///dev/ttyUSB0?baud=57600``
is a telemetry radio; a port that vanishes (USB unplugged) is reopened with
the same backoff.

A stream may cut a frame anywhere, so each connection has its own
:class:`~mavframe.frames.StreamFramer` and hands on only whole frames; the
link above sees the same shape as a UDP datagram. A client that cannot keep up
(more than ``MAX_PENDING_SEND_BYTES`` waiting) loses frames, counted, rather
than making the proxy buffer without bound.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from mavframe.frames import StreamFramer
from mitm_proxy.net.endpoints import MAX_PENDING_SEND_BYTES, BaseEndpoint, EndpointError, Role, _fmt
from mitm_proxy.net.rules import NO_RULES, EndpointRules
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)

BACKOFF_FIRST_S = 0.25
BACKOFF_MAX_S = 5.0
STABLE_S = 2.0  # a connection that lasted this long resets the backoff


class _Connection(asyncio.Protocol):
    """One TCP connection or serial port: reassembles frames and hands them to its endpoint."""

    def __init__(self, owner: BaseEndpoint, on_lost: Callable[[_Connection, Exception | None], None]) -> None:
        self.owner = owner
        self.framer = StreamFramer()
        self.transport: asyncio.WriteTransport | None = None
        self.peer: Any = None
        self.lost = asyncio.get_running_loop().create_future()
        self._on_lost = on_lost

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.peer = transport.get_extra_info("peername")

    def data_received(self, data: bytes) -> None:
        rx_s = time.monotonic()
        self.owner.rx += 1
        whole = self.framer.feed(data)
        if whole:
            self.owner._deliver(whole, rx_s)

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        if not self.lost.done():
            self.lost.set_result(exc)
        self._on_lost(self, exc)

    def write(self, data: bytes) -> bool:
        transport = self.transport
        if transport is None or transport.is_closing():
            return False
        if transport.get_write_buffer_size() > MAX_PENDING_SEND_BYTES:
            detail = f"{_fmt(self.peer)} has more than {MAX_PENDING_SEND_BYTES} bytes waiting"
            self.owner._fault("send_overflow", detail)
            return False
        transport.write(data)
        return True

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


class _Reconnecting(BaseEndpoint):
    """An endpoint with one connection at a time, opened by ``_connect`` and reopened with backoff."""

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        super().__init__(endpoint, name, role, rules)
        self.connection: _Connection | None = None
        self.connects = 0
        self._task: asyncio.Task[None] | None = None

    async def open(self) -> _Reconnecting:
        self._task = asyncio.create_task(self._run(), name=f"connect {self.name}")
        return self

    async def _connect(self, factory: Any) -> None:
        raise NotImplementedError

    async def _run(self) -> None:
        backoff = BACKOFF_FIRST_S
        while True:
            conn: _Connection | None = None

            def factory() -> _Connection:
                nonlocal conn
                conn = _Connection(self, lambda _c, _e: None)
                return conn

            try:
                await self._connect(factory)
            except (OSError, ValueError) as exc:  # refused, unreachable, no such device
                self._fault("connect_failed", f"{exc}; retrying every {BACKOFF_MAX_S:g} s at most")
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, BACKOFF_MAX_S)
                continue
            assert conn is not None
            self.connection, self.peer = conn, conn.peer or self.endpoint.host
            self.connects += 1
            self._cleared("connect_failed")
            self._cleared("not_connected")
            log.info("endpoint.connected",
                     extra={"endpoint": self.name, "url": str(self.endpoint), "peer": _fmt(self.peer)})  # fmt: skip
            up_s = time.monotonic()
            exc = await conn.lost
            self.connection = None
            self._fault("disconnected", f"connection closed ({exc or 'by the peer'}); reconnecting")
            self._cleared("disconnected")  # every drop is news
            if time.monotonic() - up_s >= STABLE_S:  # a peer that hangs up at once is retried with backoff
                backoff = BACKOFF_FIRST_S
            else:
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, BACKOFF_MAX_S)

    def _write(self, data: bytes) -> bool:
        conn = self.connection
        if conn is None or not conn.write(data):
            if conn is None:
                self._fault("not_connected", "not connected yet; dropping until the connection is up")
            return False
        self.tx += 1
        return True

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self.connection is not None:
            self.connection.close()
            self.connection = None


class TcpClientEndpoint(_Reconnecting):
    """``tcp://HOST:PORT``: connect to a MAVLink TCP server, reconnect when it goes."""

    async def _connect(self, factory: Any) -> None:
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        transport, _ = await loop.create_connection(factory, ep.host, ep.port)
        sockname = transport.get_extra_info("sockname")
        self.local = None if sockname is None else tuple(sockname[:2])  # type: ignore[assignment]


class SerialEndpoint(_Reconnecting):
    """``serial:///dev/ttyUSB0?baud=57600``: a telemetry radio (8N1, no flow control)."""

    async def _connect(self, factory: Any) -> None:
        try:
            import serial_asyncio_fast
        except ImportError as exc:  # pragma: no cover - a runtime dependency
            raise EndpointError(f"{self.name} {self.endpoint}: pyserial-asyncio-fast is not installed") from exc
        loop = asyncio.get_running_loop()
        await serial_asyncio_fast.create_serial_connection(
            loop, factory, self.endpoint.host, baudrate=self.endpoint.port
        )


class TcpServerEndpoint(BaseEndpoint):
    """``tcpin://HOST:PORT``: a TCP server; every connected client is a peer."""

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        super().__init__(endpoint, name, role, rules)
        self.clients: list[_Connection] = []
        self.connects = 0
        self._server: asyncio.Server | None = None

    async def open(self) -> TcpServerEndpoint:
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        try:
            self._server = await loop.create_server(self._accept, ep.host, ep.port, reuse_address=True)
        except OSError as exc:
            raise EndpointError(exc.errno, f"{self.name} {ep}: cannot listen on {ep.host}:{ep.port}: "
                                           f"{exc.strerror or exc}") from exc  # fmt: skip
        sock = self._server.sockets[0]
        self.local = tuple(sock.getsockname()[:2])  # type: ignore[assignment]
        return self

    def _accept(self) -> _Connection:
        conn = _Connection(self, self._gone)
        self.clients.append(conn)
        self.connects += 1
        loop = asyncio.get_running_loop()
        loop.call_soon(self._greet, conn)
        return conn

    def _greet(self, conn: _Connection) -> None:
        self.peer = conn.peer
        self._cleared("no_peer")
        log.info("endpoint.client",
                 extra={"endpoint": self.name, "peer": _fmt(conn.peer), "clients": len(self.clients)})  # fmt: skip

    def _gone(self, conn: _Connection, exc: Exception | None) -> None:
        with contextlib.suppress(ValueError):
            self.clients.remove(conn)
        log.info("endpoint.client_gone", extra={"endpoint": self.name, "peer": _fmt(conn.peer),
                                                "clients": len(self.clients)})  # fmt: skip
        self.peer = self.clients[-1].peer if self.clients else None

    def _write(self, data: bytes) -> bool:
        if not self.clients:
            self._fault("no_peer", "no client connected yet; dropping until one does")
            return False
        sent = False
        for conn in self.clients:
            sent = conn.write(data) or sent
        if sent:
            self.tx += 1
        return sent

    def close(self) -> None:
        for conn in list(self.clients):
            conn.close()
        if self._server is not None:
            self._server.close()
            self._server = None

    def snapshot(self) -> dict[str, Any]:
        out = super().snapshot()
        out["clients"] = len(self.clients)
        return out

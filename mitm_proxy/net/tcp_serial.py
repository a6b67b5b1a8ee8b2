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
link above sees the same shape as a UDP datagram.

No peer can stall the others (docs/security.md). What arrives is framed
``SLICE_BYTES`` at a time, one slice per turn of the event loop (reading
paused meanwhile), so a 256 kB read cannot hold the loop for other vehicles.
Bytes that are not MAVLink count against each connection's own budget of
``GARBAGE_BYTES_PER_S`` (one client's garbage costs only that client): past it
a ``tcpin`` client is evicted, and a ``tcp``/``serial`` link drops what arrives
for the rest of that second. A ``tcpin`` endpoint serves at most
``max_clients`` clients and ``max_clients_per_address`` from one address (URL
options, defaults ``DEFAULT_MAX_CLIENTS`` and ``DEFAULT_MAX_PER_ADDRESS``; one
more is refused), and drops a client that has not sent one whole MAVLink frame
(a GCS sends HEARTBEAT at 1 Hz) within ``idle_s`` of connecting (default
``DEFAULT_IDLE_S``; 0: never), so silent connections cannot hold the seats. A client whose send
buffer stays over ``MAX_PENDING_SEND_BYTES`` for ``SLOW_CLIENT_S`` is evicted
(meanwhile it loses frames, counted) rather than making the proxy buffer
without bound. A ``tcp`` peer that stays silent for ``SILENT_PEER_S`` (one that
accepts and never sends, or a half-open connection) is dropped and dialled
again; TCP keepalive finds a vanished peer on ``tcpin`` too. Each of these is
counted in the endpoint's faults; what a client can repeat at will (refusals,
evictions, connects) is logged at most once per 10 s per kind, with the count.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from mavframe.frames import StreamFramer, tiles
from mitm_proxy.net.endpoints import MAX_PENDING_SEND_BYTES, BaseEndpoint, EndpointError, Role, _fmt
from mitm_proxy.net.rules import NO_RULES, EndpointRules
from secuav_common.loading import InputError
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)

BACKOFF_FIRST_S = 0.25
BACKOFF_MAX_S = 5.0
STABLE_S = 2.0  # a connection that lasted this long resets the backoff
# Framing crafted bytes costs up to ~2 us a byte (benchmarks/framing_garbage_bench.py), clean frames ~0.3:
# 2 kB a turn holds the loop ~4 ms at worst, and 64 kB of garbage a second costs at most ~13 % of a core.
# A link's own traffic never comes near the budget (a stream that tiles costs nothing against it).
SLICE_BYTES = 2048
GARBAGE_BYTES_PER_S = 64 * 1024
DEFAULT_MAX_CLIENTS = 16
DEFAULT_MAX_PER_ADDRESS = 4  # a few ground tools on one machine; one address cannot take every seat
DEFAULT_IDLE_S = 15.0  # a tcpin client that sends no MAVLink frame this long after connecting gives its seat back
SLOW_CLIENT_S = 5.0  # a tcpin client that reads nothing for this long while we send is evicted
SILENT_PEER_S = 10.0  # an autopilot sends HEARTBEAT at 1 Hz; a tcp peer silent this long is dialled again
KEEPALIVE = {"TCP_KEEPIDLE": 5, "TCP_KEEPINTVL": 2, "TCP_KEEPCNT": 3}  # a vanished peer is found in ~11 s


def _keepalive(transport: asyncio.BaseTransport) -> None:
    sock = transport.get_extra_info("socket")
    if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
        return
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        for name, value in KEEPALIVE.items():
            if hasattr(socket, name):
                sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)


class _GarbageBudget:
    """Bytes that were not MAVLink, in the current one-second window of one connection."""

    __slots__ = ("spent", "window_s")

    def __init__(self) -> None:
        self.window_s = -1.0
        self.spent = 0

    def spend(self, size: int, now_s: float) -> bool:
        """Count ``size`` bytes; True while the window's total stays within the budget."""
        if now_s - self.window_s >= 1.0:
            self.window_s, self.spent = now_s, 0
        self.spent += size
        return self.spent <= GARBAGE_BYTES_PER_S

    def over(self, now_s: float) -> bool:
        return now_s - self.window_s < 1.0 and self.spent > GARBAGE_BYTES_PER_S


class _Connection(asyncio.Protocol):
    """One TCP connection or serial port: reassembles frames, a slice per loop turn, and hands them on."""

    def __init__(self, owner: _StreamEndpoint, on_lost: Callable[[_Connection, Exception | None], None]) -> None:
        self.owner = owner
        self.framer = StreamFramer()
        self.transport: asyncio.WriteTransport | None = None
        self.peer: Any = None
        self.lost = asyncio.get_running_loop().create_future()
        self.last_rx_s = self.since_s = time.monotonic()
        self.spoke = False  # sent a whole MAVLink frame: a peer, not a silent connection holding a seat
        self.garbage = _GarbageBudget()  # its own: another client's garbage never costs this one
        self._on_lost = on_lost
        self._inbox: list[bytes] = []  # reads not yet framed; the first from _inbox_at on
        self._inbox_at = 0
        self._draining = False
        self._full_since_s: float | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.peer = transport.get_extra_info("peername")
        _keepalive(transport)

    def data_received(self, data: bytes) -> None:
        self.last_rx_s = time.monotonic()
        self.owner.rx += 1
        self._inbox.append(data)
        if not self._draining and self.transport is not None:
            self._draining = True
            self.transport.pause_reading()  # type: ignore[attr-defined]
            asyncio.get_running_loop().call_soon(self._drain)

    def _drain(self) -> None:
        """Frame one slice of what arrived; come back next turn for the rest, then read again."""
        transport = self.transport
        if transport is None or transport.is_closing():
            self._inbox.clear()
            self._inbox_at = 0
            self._draining = False
            return
        head, at = self._inbox[0], self._inbox_at
        piece = head[at : at + SLICE_BYTES]  # an offset, not the rest copied each turn (a 256 kB read is 128 turns)
        if at + SLICE_BYTES < len(head):
            self._inbox_at = at + SLICE_BYTES
        else:
            self._inbox.pop(0)
            self._inbox_at = 0
        self._take(piece, time.monotonic())
        if self._inbox and self.transport is not None:
            asyncio.get_running_loop().call_soon(self._drain)
            return
        self._draining = False
        if self.transport is not None and not self.transport.is_closing():
            self.transport.resume_reading()  # type: ignore[attr-defined]

    def _take(self, piece: bytes, rx_s: float) -> None:
        owner = self.owner
        if self.garbage.over(rx_s):
            owner.over_budget(self, len(piece))
            return
        whole = self.framer.feed(piece)
        if not whole:
            return
        if tiles(whole):
            self.spoke = True  # only MAVLink earns a tcpin seat: garbage within the budget does not
        elif not self.garbage.spend(len(whole), rx_s):
            owner.over_budget(self, len(whole))
            return
        owner._deliver(whole, rx_s)

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
            now_s = time.monotonic()
            if self._full_since_s is None:
                self._full_since_s = now_s
            detail = f"{_fmt(self.peer)} has more than {MAX_PENDING_SEND_BYTES} bytes waiting"
            self.owner._fault("send_overflow", detail)
            if now_s - self._full_since_s > SLOW_CLIENT_S:
                self.owner.too_slow(self)
            return False
        self._full_since_s = None
        transport.write(data)
        return True

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def abort(self) -> None:
        """Close now, dropping whatever is still waiting to be sent."""
        if self.transport is not None:
            self.transport.abort()


class _StreamEndpoint(BaseEndpoint):
    """What TCP and serial endpoints share: the garbage budget and what to do with a peer that abuses it."""

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        super().__init__(endpoint, name, role, rules)
        self.dropped_bytes = 0  # dropped unread: over the garbage budget, or from an evicted client

    def snapshot(self) -> dict[str, Any]:
        out = super().snapshot()
        if self.dropped_bytes:
            out["dropped_bytes"] = self.dropped_bytes
        return out

    def over_budget(self, conn: _Connection, size: int) -> None:
        """A connection sent more than the budget of non-MAVLink bytes: drop them (subclasses may evict it)."""
        self.dropped_bytes += size
        self._fault("over_budget", f"more than {GARBAGE_BYTES_PER_S} bytes that are not MAVLink in a second from "
                                   f"{_fmt(conn.peer)}: dropped unread until the second is over")  # fmt: skip
        conn.framer = StreamFramer()  # what was held is cut off from what follows

    def too_slow(self, conn: _Connection) -> None:
        """A peer read nothing for ``SLOW_CLIENT_S`` while we sent: drop it (it reconnects or stays gone)."""
        self._event("slow_peer_evicted", f"{_fmt(conn.peer)} read nothing for {SLOW_CLIENT_S:g} s; disconnected")
        conn.abort()


class _Reconnecting(_StreamEndpoint):
    """An endpoint with one connection at a time, opened by ``_connect`` and reopened with backoff."""

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        super().__init__(endpoint, name, role, rules)
        self.connection: _Connection | None = None
        self.connects = 0
        self._task: asyncio.Task[None] | None = None

    silent_after_s: float | None = None  # TCP: SILENT_PEER_S; a radio may be silent while its vehicle is off

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
            exc = await self._until_lost(conn)
            self.connection = None
            self._fault("disconnected", f"connection closed ({exc or 'by the peer'}); reconnecting")
            self._cleared("disconnected")  # every drop is news
            if time.monotonic() - up_s >= STABLE_S:  # a peer that hangs up at once is retried with backoff
                backoff = BACKOFF_FIRST_S
            else:
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, BACKOFF_MAX_S)

    async def _until_lost(self, conn: _Connection) -> Exception | None:
        """Wait for the connection to end; a peer silent for ``silent_after_s`` is cut off first."""
        limit = self.silent_after_s
        while limit is not None:
            try:
                return await asyncio.wait_for(asyncio.shield(conn.lost), timeout=limit / 4)
            except TimeoutError:
                quiet_s = time.monotonic() - conn.last_rx_s
                if quiet_s > limit:
                    self._fault("silent_peer", f"nothing from {_fmt(conn.peer)} for {quiet_s:.0f} s; dialling again")
                    self._cleared("silent_peer")  # every one is news
                    conn.abort()
                    break
        return await conn.lost

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
    """``tcp://HOST:PORT``: connect to a MAVLink TCP server, reconnect when it goes or falls silent."""

    silent_after_s = SILENT_PEER_S

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


class TcpServerEndpoint(_StreamEndpoint):
    """``tcpin://HOST:PORT``: a TCP server; every connected client is a peer."""

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        super().__init__(endpoint, name, role, rules)
        self.clients: list[_Connection] = []
        self.connects = 0
        self.max_clients = _count_option(endpoint, "max_clients", DEFAULT_MAX_CLIENTS)
        self.max_per_address = _count_option(endpoint, "max_clients_per_address", DEFAULT_MAX_PER_ADDRESS)
        self.idle_s = idle_s_of(endpoint)
        self.per_address: Counter[str] = Counter()
        self._server: asyncio.Server | None = None
        self._idle_task: asyncio.Task[None] | None = None

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
        if self.idle_s > 0:
            self._idle_task = asyncio.create_task(self._evict_idle(), name=f"idle {self.name}")
        return self

    def _accept(self) -> asyncio.Protocol:
        # The peer's address is known only once the transport exists: the caps are checked there.
        return _Admission(self)

    def admit(self, transport: asyncio.BaseTransport) -> _Connection | None:
        """A new client, or None when it was refused (and cut off): the endpoint or its address is full."""
        peer = transport.get_extra_info("peername")
        address = _address(peer)
        if len(self.clients) >= self.max_clients:
            why = f"{self.max_clients} clients are connected, the most this endpoint serves (URL option max_clients)"
        elif self.per_address[address] >= self.max_per_address:
            why = (f"{self.max_per_address} clients are connected from {address}, the most one address may hold "
                   "(URL option max_clients_per_address)")  # fmt: skip
        else:
            conn = _Connection(self, self._gone)
            self.clients.append(conn)
            self.per_address[address] += 1
            self.connects += 1
            transport.set_protocol(conn)
            conn.connection_made(transport)
            self.peer = conn.peer
            self._cleared("no_peer")
            self.events.event("endpoint.client", logging.INFO, endpoint=self.name, peer=_fmt(conn.peer),
                              clients=len(self.clients))  # fmt: skip
            return conn
        self._event("client_refused", f"{_fmt(peer)}: {why}")
        transport.abort()  # type: ignore[attr-defined]
        return None

    def over_budget(self, conn: _Connection, size: int) -> None:
        """A client that floods the endpoint with bytes that are not MAVLink is disconnected."""
        self.dropped_bytes += size
        self._event("client_evicted", f"{_fmt(conn.peer)} sent more than {GARBAGE_BYTES_PER_S} bytes that are not "
                                      "MAVLink in a second; disconnected")  # fmt: skip
        conn.abort()

    async def _evict_idle(self) -> None:
        """Drop the clients that sent no whole frame within ``idle_s`` of connecting: a connection that never
        speaks MAVLink gives its seat back. One that has spoken keeps it however quiet it gets later (a script
        that waits for a long manoeuvre between two commands)."""
        while True:
            await asyncio.sleep(max(self.idle_s / 4, 0.05))
            now = time.monotonic()
            for conn in [c for c in self.clients if not c.spoke and now - c.since_s > self.idle_s]:
                self._event("client_idle", f"no MAVLink from {_fmt(conn.peer)} within {self.idle_s:g} s of "
                                           "connecting (URL option idle_s); disconnected")  # fmt: skip
                conn.abort()

    def _gone(self, conn: _Connection, exc: Exception | None) -> None:
        with contextlib.suppress(ValueError):
            self.clients.remove(conn)
            address = _address(conn.peer)
            self.per_address[address] -= 1
            if self.per_address[address] <= 0:
                del self.per_address[address]
        self.events.event("endpoint.client_gone", logging.INFO, endpoint=self.name, peer=_fmt(conn.peer),
                          clients=len(self.clients))  # fmt: skip
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
        if self._idle_task is not None:
            self._idle_task.cancel()
            self._idle_task = None
        for conn in list(self.clients):
            conn.close()
        if self._server is not None:
            self._server.close()
            self._server = None

    def snapshot(self) -> dict[str, Any]:
        out = super().snapshot()
        out["clients"] = len(self.clients)
        out["max_clients"] = self.max_clients
        return out


class _Admission(asyncio.Protocol):
    """A client just accepted: admitted (its transport then talks to its :class:`_Connection`) or refused."""

    def __init__(self, owner: TcpServerEndpoint) -> None:
        self.owner = owner

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.owner.admit(transport)


def _address(peer: Any) -> str:
    return str(peer[0]) if isinstance(peer, tuple) and peer else str(peer)


def _count_option(endpoint: Endpoint, name: str, default: int) -> int:
    """A whole-number URL option of a ``tcpin`` endpoint (at least 1)."""
    text = endpoint.option(name)
    if text is None:
        return default
    if not text.isdigit() or int(text) < 1:
        raise InputError("<url>", f"{endpoint.without_options()} option {name}", text, "must be a number >= 1")
    return int(text)


def idle_s_of(endpoint: Endpoint) -> float:
    """The ``idle_s`` URL option of a ``tcpin`` endpoint: seconds a new client has to send its first frame."""
    text = endpoint.option("idle_s")
    if text is None:
        return DEFAULT_IDLE_S
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value < 1e6:
        raise InputError("<url>", f"{endpoint.without_options()} option idle_s", text,
                         "must be seconds >= 0 (0: never drop a silent client)")  # fmt: skip
    return value

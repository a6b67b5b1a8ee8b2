"""The asyncio edge: one UDP socket per vehicle, MAVSDK/mavlink-router URL semantics.

``udpout://HOST:PORT`` sends to that fixed peer from an ephemeral port (PX4
SITL's ``-o`` port); ``udpin://HOST:PORT`` binds there. Either way the link
also answers whoever sends to it, so a GCS can talk to the vehicle's port
directly; such peers are dropped after ``PEER_TIMEOUT_S`` of silence.

Frames queued during one tick leave together, several per datagram (at
most ``MAX_DATAGRAM`` bytes) as PX4 does: one syscall per tick instead of per
message is most of the cost of sending at 16 vehicles.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections.abc import Callable

from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)
PEER_TIMEOUT_S = 10.0
MAX_DATAGRAM = 1400  # fits an Ethernet MTU when the link leaves the machine
Address = tuple[str, int]


async def _lookup(addr: Address) -> Address:
    """``(ip, port)`` for ``(host, port)``, IPv4 first; an unknown name is an ``OSError`` naming it."""
    host, port = addr
    try:
        infos = await asyncio.get_running_loop().getaddrinfo(host, port, family=socket.AF_INET, type=socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise OSError(f"cannot resolve {host!r}: {exc.strerror}") from None
    return infos[0][4][0], port


class UdpLink(asyncio.DatagramProtocol):
    """Moves datagrams between a socket and a receive callback; counts what it cannot send."""

    def __init__(
        self,
        endpoint: Endpoint,
        on_datagram: Callable[[bytes, float], None],
        also_to: tuple[Address, ...] = (),
    ) -> None:
        self.endpoint = endpoint
        self._on_datagram = on_datagram
        self._transport: asyncio.DatagramTransport | None = None
        self._fixed: Address | None = endpoint.address if endpoint.mode == "udpout" else None
        # Further fixed peers (a GCS on 14550 beside MAVSDK on 14540, as PX4 SITL streams to both).
        self._also = tuple(a for a in also_to if a != self._fixed)
        self._peers: dict[Address, float] = {}
        self._pending: list[bytes] = []
        self._pending_len = 0
        self.send_errors = 0
        self.rx_datagrams = 0
        self.tx_datagrams = 0
        self.on_after_receive: Callable[[], None] | None = None

    async def open(self) -> UdpLink:
        loop = asyncio.get_running_loop()
        # Names (localhost, a compose service) are looked up once, here: replies are compared with the
        # address, and sending to a name would look it up again for every datagram.
        if self._fixed is not None:
            self._fixed = await _lookup(self._fixed)
        self._also = tuple([await _lookup(a) for a in self._also])
        if self.endpoint.mode == "udpin":
            local: Address = self.endpoint.address
        else:
            # A socket bound to loopback cannot reach another host: bind wide only when a peer is elsewhere.
            hosts = [h for h in (self._fixed[0] if self._fixed else None, *(a[0] for a in self._also)) if h]
            local = ("127.0.0.1" if all(h.startswith("127.") for h in hosts) else "0.0.0.0", 0)
        await loop.create_datagram_endpoint(lambda: self, local_addr=local)
        return self

    @property
    def local_address(self) -> Address:
        assert self._transport is not None
        return self._transport.get_extra_info("sockname")[:2]

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Address) -> None:
        now = time.monotonic()
        self.rx_datagrams += 1
        if addr[:2] != self._fixed and addr[:2] not in self._also:
            self._peers[addr[:2]] = now
        self._on_datagram(data, now)
        if self.on_after_receive is not None:
            self.on_after_receive()

    def error_received(self, exc: Exception) -> None:
        # ICMP "port unreachable" while nobody listens yet (the proxy or MAVSDK starts later): keep going.
        self.send_errors += 1

    def send(self, frame: bytes) -> None:
        """Queue a frame; :meth:`flush` sends the queue."""
        if self._pending_len + len(frame) > MAX_DATAGRAM:
            self.flush()
        self._pending.append(frame)
        self._pending_len += len(frame)

    def flush(self) -> None:
        if not self._pending:
            return
        datagram = b"".join(self._pending)
        self._pending.clear()
        self._pending_len = 0
        t = self._transport
        if t is None or t.is_closing():
            return
        if self._fixed is not None:
            t.sendto(datagram, self._fixed)
            self.tx_datagrams += 1
        for addr in self._also:
            t.sendto(datagram, addr)
            self.tx_datagrams += 1
        if self._peers:
            now = time.monotonic()
            for addr, seen in list(self._peers.items()):
                if now - seen > PEER_TIMEOUT_S:
                    del self._peers[addr]
                    continue
                t.sendto(datagram, addr)
                self.tx_datagrams += 1

    def close(self) -> None:
        self.flush()
        if self._transport is not None:
            self._transport.close()

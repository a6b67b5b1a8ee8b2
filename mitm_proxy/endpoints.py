"""asyncio UDP endpoints as MAVSDK and mavlink-router write them.

``udpin://HOST:PORT`` binds HOST:PORT and answers the peer that sent first. A
datagram from anyone else is a stranger's: counted, logged once, dropped, so
one spoofed datagram cannot take the ground side over and receive the GCS's
commands. Only when the pinned peer has been silent for ``takeover_after_s``
does a new sender take its place (a vehicle that restarts from a new source
port is followed that way, and said so once);
``udpout://HOST:PORT`` sends to a fixed peer from an ephemeral port and takes
replies on that port (how MAVSDK, QGroundControl and MAVProxy answer).

An endpoint only moves datagrams: the link above it decides what they mean.
Faults of the network never close it: an ICMP "port unreachable" from a ground
client that went away (reported by the kernel on the standard loop, see
:func:`_reports_icmp`), a send buffer that fills, a datagram before anyone has
sent to a ``udpin`` endpoint. Each is counted and logged once per kind (and
again only after the endpoint saw it clear), never per datagram.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import sys
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)

Receiver = Callable[[bytes, float], None]  # datagram, monotonic arrival time
RCVBUF_BYTES = 4 * 1024 * 1024  # ride out bursts (the kernel may cap it at net.core.rmem_max)
MAX_PENDING_SEND_BYTES = 1024 * 1024  # beyond this, drop rather than queue without bound
_LOOPBACK_HOSTS = {"127.0.0.1", "localhost"}
IP_RECVERR = 11  # Linux <linux/in.h>; Python's socket module does not export it
# A udpin peer silent this long may be replaced by a new sender: a vehicle streams many times a
# second and a GCS sends its HEARTBEAT at 1 Hz, so only a peer that has really gone is replaced.
DEFAULT_TAKEOVER_S = 3.0


class UdpEndpoint(asyncio.DatagramProtocol):
    """One UDP socket of the proxy.

    ``receiver`` is called with each datagram and its arrival time: the link's
    (vehicle side) or a :class:`~mitm_proxy.link.GroundRouter` (ground side,
    which hands uplink to the link or links that share the endpoint).
    ``faults`` counts what went wrong by kind; ``rx``/``tx`` count datagrams.
    """

    def __init__(self, endpoint: Endpoint, name: str, takeover_after_s: float = DEFAULT_TAKEOVER_S) -> None:
        self.endpoint = endpoint
        self.name = name
        self.takeover_after_s = takeover_after_s
        self._peer_heard_s = -math.inf  # when the pinned peer last sent
        self.receiver: Receiver | None = None
        self.peer: tuple[str, int] | None = endpoint.address if endpoint.mode == "udpout" else None
        self._udpin = endpoint.mode == "udpin"
        self.local: tuple[str, int] | None = None
        self.rx = 0
        self.tx = 0
        self.faults: Counter[str] = Counter()
        self._reported: set[str] = set()
        self._transport: asyncio.DatagramTransport | None = None

    async def open(self) -> UdpEndpoint:
        """Bind the socket (``udpin``: HOST:PORT; ``udpout``: an ephemeral port). ``OSError`` if taken."""
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        if ep.mode == "udpin":
            local: tuple[str, int] = (ep.host, ep.port)
        else:  # reply port on the interface that reaches the peer; loopback peers get a loopback socket
            local = ("127.0.0.1" if ep.host in _LOOPBACK_HOSTS else "", 0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            if _reports_icmp(loop):
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.IPPROTO_IP, IP_RECVERR, 1)
            sock.bind(local)
            sock.setblocking(False)
            transport, _ = await loop.create_datagram_endpoint(lambda: self, sock=sock)
        except BaseException:
            sock.close()
            raise
        self._transport = transport
        self.local = sock.getsockname()[:2]
        log.debug("endpoint.open", extra={"endpoint": self.name, "url": str(ep), "local": _fmt(self.local)})
        return self

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    # -- receiving ---------------------------------------------------------------
    def datagram_received(self, data: bytes, addr: tuple[str, int] | Any) -> None:
        rx_s = time.monotonic()
        self.rx += 1
        if addr == self.peer:  # the common case, both modes: the peer we know
            self._peer_heard_s = rx_s
        elif self._udpin:
            peer = (addr[0], addr[1])
            if self.peer is not None:
                if rx_s - self._peer_heard_s < self.takeover_after_s:
                    self._fault("stranger", f"datagram from {_fmt(peer)} while {_fmt(self.peer)} is the peer")
                    return
                self.faults["peer_changed"] += 1
                log.info("endpoint.peer_changed",
                         extra={"endpoint": self.name, "old": _fmt(self.peer), "new": _fmt(peer)})  # fmt: skip
                self._reported.discard("stranger")  # a new peer: strangers to it are news again
            self.peer = peer
            self._peer_heard_s = rx_s
        elif not _same_host_port(addr, self.endpoint):
            # A udpout socket is not connected (so a vanished peer cannot make it unusable); anything
            # from a stranger is not ours to forward.
            self._fault("foreign_sender", f"datagram from {_fmt(addr)}, expected {_fmt(self.peer)}")
            return
        if self._reported:
            self._reported.discard("unreachable")
        if self.receiver is not None:
            self.receiver(data, rx_s)

    def error_received(self, exc: Exception) -> None:
        """ICMP errors (a ground client that closed its port): count, keep the socket."""
        kind = "unreachable" if isinstance(exc, ConnectionRefusedError) else "socket_error"
        self._fault(kind, str(exc))

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            log.warning("endpoint.lost", extra={"endpoint": self.name, "error": str(exc)})

    # -- sending -----------------------------------------------------------------
    def send(self, data: bytes) -> bool:
        """Send one datagram to the peer; False (counted) when there is none yet or the socket is backed up."""
        transport = self._transport
        if transport is None or self.peer is None:
            self._fault("no_peer", "nobody has sent to this udpin endpoint yet; dropping until someone does")
            return False
        if transport.get_write_buffer_size() > MAX_PENDING_SEND_BYTES:
            self._fault("send_overflow", f"more than {MAX_PENDING_SEND_BYTES} bytes waiting to be sent")
            return False
        try:
            transport.sendto(data, self.peer)
        except OSError as exc:  # pragma: no cover - asyncio reports most send errors via error_received
            self._fault("socket_error", str(exc))
            return False
        self.tx += 1
        if self._reported:
            self._reported.discard("no_peer")  # the condition ended: log it again if it comes back
        return True

    # -- fault bookkeeping ---------------------------------------------------------
    def _fault(self, kind: str, detail: str) -> None:
        self.faults[kind] += 1
        if kind not in self._reported:
            self._reported.add(kind)
            log.warning(f"endpoint.{kind}", extra={"endpoint": self.name, "url": str(self.endpoint), "detail": detail})

    def snapshot(self) -> dict[str, Any]:
        return {"url": str(self.endpoint), "peer": _fmt(self.peer), "rx": self.rx, "tx": self.tx,
                "faults": dict(self.faults)}  # fmt: skip


def _reports_icmp(loop: asyncio.AbstractEventLoop) -> bool:
    """Whether to ask the kernel for ICMP errors on this unconnected socket (``IP_RECVERR``, Linux).

    Then a ground client that went away shows up as ``unreachable`` (counted,
    logged once) instead of nothing. Only on the standard loop: uvloop 0.2x
    crashes (SIGSEGV) on the second such error, so under uvloop a vanished
    peer stays silent; forwarding is the same either way.
    """
    return type(loop).__module__.startswith("asyncio") and sys.platform == "linux"


def _same_host_port(addr: Any, ep: Endpoint) -> bool:
    """``localhost`` in the URL still matches replies from 127.0.0.1."""
    return bool(addr[1] == ep.port and ep.host in _LOOPBACK_HOSTS and addr[0] in _LOOPBACK_HOSTS)


def _fmt(addr: Any) -> str:
    return "-" if addr is None else f"{addr[0]}:{addr[1]}"

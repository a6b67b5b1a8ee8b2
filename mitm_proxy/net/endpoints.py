"""The proxy's endpoints: the base class and UDP here, TCP and serial in :mod:`mitm_proxy.net.tcp_serial`
(:func:`mitm_proxy.net.factory.make_endpoint` picks the class for a URL).

``udpin://HOST:PORT`` binds HOST:PORT and answers the peer that sent first. A
datagram from anyone else is a stranger's: counted, logged once, dropped, so
one spoofed datagram cannot take the ground side over and receive the GCS's
commands. Only when the pinned peer has been silent for ``takeover_after_s``
does a new sender take its place (a vehicle that restarts from a new source
port is followed that way, and said so once);
``udpout://HOST:PORT`` sends to a fixed peer from an ephemeral port and takes
replies on that port (how MAVSDK, QGroundControl and MAVProxy answer). A host
name (``localhost``, a compose service name) is resolved once when the
endpoint opens, IPv4 first; replies are compared with the resolved address.

An endpoint only moves bytes and applies its routing rules
(:mod:`mitm_proxy.net.rules`: allow/deny lists, listen-only): the link above it
decides what frames mean. Faults of the network never close it: an ICMP "port
unreachable" from a ground client that went away (reported by the kernel on
the standard loop, see :func:`_reports_icmp`), a send buffer that fills, a
datagram before anyone has sent to a ``udpin`` endpoint. Each is counted and
logged once per kind (and again only after the endpoint saw it clear), never
per datagram.

A peer that answers with ICMP port unreachable is *muted*: nobody listens there
(the default configuration names two ground ports; often only one has a client),
and every datagram sent to it would cost a send and the kernel's ICMP error for
nothing. While muted, the endpoint sends one datagram per ``PROBE_INTERVAL_S``
(a probe) and drops the others, counted (``muted_dropped``); it resumes as soon
as the peer sends us a datagram, or when a probe drew no ICMP error within
``PROBE_CONFIRM_S``. Each transition is one log line (``endpoint.muted``,
``endpoint.resumed``). It needs the kernel's ICMP reports (``IP_RECVERR``): on
Linux, on the fast path's endpoints and on the standard loop's (not on uvloop's
pure-Python transport, see :func:`_reports_icmp`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import ipaddress
import logging
import math
import socket
import sys
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, Literal

from mavframe import frames
from mavframe.codec import MAVLINK_MAP
from mavframe.packet import Direction
from mitm_proxy.net.rules import NO_RULES, EndpointGate, EndpointRules
from secuav_common.logs import RateLimitedLog
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)

Receiver = Callable[[bytes, float], None]  # bytes, monotonic arrival time
Role = Literal["vehicle", "ground"]
RCVBUF_BYTES = 4 * 1024 * 1024  # ride out bursts (the kernel may cap it at net.core.rmem_max)
MAX_PENDING_SEND_BYTES = 1024 * 1024  # beyond this, drop rather than queue without bound
IP_RECVERR = 11  # Linux <linux/in.h>; Python's socket module does not export it
# A udpin peer silent this long may be replaced by a new sender: a vehicle streams many times a
# second and a GCS sends its HEARTBEAT at 1 Hz, so only a peer that has really gone is replaced.
DEFAULT_TAKEOVER_S = 3.0
# A MAVLink 2 frame is at most 280 bytes and senders pack frames up to one MTU (PX4: 1500 bytes). A larger
# datagram is dropped unread and counted as "oversize": splitting 64 kB of crafted bytes took 6-20 ms of
# loop time (frames.split), reading the length takes nothing.
MAX_DATAGRAM_BYTES = 8192
# A muted peer (it answered with ICMP port unreachable) gets one datagram this often, as a probe ...
PROBE_INTERVAL_S = 0.25
# ... and counts as listening again when no ICMP error came back this long after a probe (on loopback the error
# is there before sendto returns; a LAN answers in milliseconds).
PROBE_CONFIRM_S = 0.1


class EndpointError(OSError):
    """An endpoint could not open; the message names the endpoint, its URL and why."""


class BaseEndpoint:
    """What every endpoint has: counters, fault bookkeeping and its routing rules.

    ``receiver`` is called with what arrives and its arrival time: the link's
    (vehicle side) or a :class:`~mitm_proxy.net.link.GroundRouter` (ground side,
    which hands uplink to the link or links that share the endpoint).
    ``faults`` counts what went wrong by kind; ``rx``/``tx`` count reads and
    writes; ``gate.dropped`` what the rules dropped.
    """

    def __init__(self, endpoint: Endpoint, name: str, role: Role = "ground", rules: EndpointRules = NO_RULES) -> None:
        self.endpoint = endpoint
        self.name = name
        self.role = role
        self.gate = EndpointGate(rules)
        self._inbound = Direction.DOWNLINK if role == "vehicle" else Direction.UPLINK
        self._outbound = Direction.UPLINK if role == "vehicle" else Direction.DOWNLINK
        self.receiver: Receiver | None = None
        self.peer: Any = None
        self.local: tuple[str, int] | None = None
        self.rx = 0
        self.tx = 0
        self.faults: Counter[str] = Counter()
        self._reported: set[str] = set()
        self.events = RateLimitedLog(log)  # what an outsider can repeat at will: one line per 10 s, with counts
        self._gated_in = self._gated_out = False
        self.set_rules(rules)

    def set_rules(self, rules: EndpointRules) -> None:
        """Replace the routing rules (runtime route changes); counters stay."""
        if rules.listen_only and self.role != "ground":
            raise ValueError(f"{self.name}: listen_only is for ground endpoints")
        self.gate.replace(rules)
        self._gated_in = rules.listen_only or self.gate.filters(self._inbound)
        self._gated_out = self.gate.filters(self._outbound)

    async def open(self) -> BaseEndpoint:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def _write(self, data: bytes) -> bool:
        raise NotImplementedError

    def send(self, data: bytes) -> bool:
        """Send towards the peer(s) what the rules let through; False (counted) when nothing left."""
        if self._gated_out:
            data = self.gate.apply(data, self._outbound)
            if not data:
                return False
        return self._write(data)

    def _deliver(self, data: bytes, rx_s: float) -> None:
        """Hand what arrived to the receiver, through the inbound rules."""
        if self._gated_in:
            if self.gate.listen_only:
                self._drop_listen_only(data)
                return
            data = self.gate.apply(data, self._inbound)
            if not data:
                return
        if self.receiver is not None:
            self.receiver(data, rx_s)

    def _drop_listen_only(self, data: bytes) -> None:
        """Count (per message: what did the spectator try to send?) and log once; nothing goes on."""
        split = frames.split(data)
        for header, _frame in split.frames:
            cls = MAVLINK_MAP.get(header.msgid)
            name = cls.msgname if cls is not None else str(header.msgid)
            self.gate.dropped["up.listen_only"] += 1
            if name not in self.gate.listen_only_sent:  # each kind of message logged once
                log.warning("endpoint.listen_only_drop", extra={"endpoint": self.name, "url": str(self.endpoint),
                                                                "dropped": name})  # fmt: skip
            self.gate.listen_only_sent[name] += 1

    # -- fault bookkeeping ---------------------------------------------------------
    def _fault(self, kind: str, detail: str) -> None:
        self.faults[kind] += 1
        if kind not in self._reported:
            self._reported.add(kind)
            log.warning(f"endpoint.{kind}", extra={"endpoint": self.name, "url": str(self.endpoint), "detail": detail})

    def _event(self, kind: str, detail: str, level: int = logging.WARNING, **fields: Any) -> None:
        """Count ``kind`` in the faults; log it rate-limited (a connect-and-garbage loop must not fill the disk)."""
        self.faults[kind] += 1
        self.events.event(f"endpoint.{kind}", level, endpoint=self.name, detail=detail, **fields)

    def _cleared(self, kind: str) -> None:
        """The condition ended: log it again if it comes back."""
        if self._reported:
            self._reported.discard(kind)

    def snapshot(self) -> dict[str, Any]:
        out = {"url": str(self.endpoint), "peer": _fmt(self.peer), "rx": self.rx, "tx": self.tx,
               "faults": dict(self.faults)}  # fmt: skip
        if self.gate.dropped or not self.gate.rules.empty:
            out["dropped"] = dict(self.gate.dropped)
        if self.gate.listen_only_sent:
            out["listen_only_dropped"] = dict(self.gate.listen_only_sent)
        return out


class UdpEndpoint(BaseEndpoint, asyncio.DatagramProtocol):
    """One UDP socket of the proxy (``udpin`` or ``udpout``, see the module doc)."""

    def __init__(
        self,
        endpoint: Endpoint,
        name: str,
        takeover_after_s: float = DEFAULT_TAKEOVER_S,
        role: Role = "ground",
        rules: EndpointRules = NO_RULES,
    ) -> None:
        super().__init__(endpoint, name, role, rules)
        self.takeover_after_s = takeover_after_s
        self._peer_heard_s = -math.inf  # when the pinned peer last sent
        self._udpin = endpoint.mode == "udpin"
        self._transport: asyncio.DatagramTransport | None = None
        self._raw: socket.socket | None = None  # to read the kernel's error queue (IP_RECVERR)
        self.muted = False  # the peer answered with ICMP port unreachable (see the module doc)
        self.mutes = 0  # times it was muted
        self.muted_dropped = 0  # datagrams not sent to it while muted
        self.probes = 0
        self._probe_s = -math.inf  # when the last probe went out while muted
        self._refused_s = -math.inf  # when the last ICMP port unreachable was reported

    async def open(self) -> UdpEndpoint:
        """Resolve, then bind (``udpin``: HOST:PORT; ``udpout``: an ephemeral port); :class:`EndpointError` if not."""
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        family, addr = await resolve(ep, socket.SOCK_DGRAM, self.name)
        if self._udpin:
            local: tuple[Any, ...] = addr
        else:  # reply port on the interface that reaches the peer; loopback peers get a loopback socket
            self.peer = addr
            loopback = ipaddress.ip_address(addr[0]).is_loopback
            local = (("::1" if family == socket.AF_INET6 else "127.0.0.1") if loopback else "", 0)
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            if self._wants_icmp(loop) and family == socket.AF_INET:
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.IPPROTO_IP, IP_RECVERR, 1)
            try:
                sock.bind(local)
            except OSError as exc:
                raise EndpointError(exc.errno, f"{self.name} {ep}: cannot bind {_fmt(local)}: {exc.strerror}") from exc
            sock.setblocking(False)
            self._raw = sock
            await self._start(loop, sock, family)
        except BaseException:
            sock.close()
            raise
        self.local = sock.getsockname()[:2]
        log.debug("endpoint.open", extra={"endpoint": self.name, "url": str(ep), "local": _fmt(self.local)})
        return self

    def _wants_icmp(self, loop: asyncio.AbstractEventLoop) -> bool:
        """Whether to ask the kernel for ICMP errors (``IP_RECVERR``): where the loop's transport survives them."""
        return _reports_icmp(loop)

    async def _start(self, loop: asyncio.AbstractEventLoop, sock: socket.socket, family: int) -> None:
        """Serve the bound socket: an asyncio transport here; the fast path's endpoint reads it itself."""
        self._transport, _ = await loop.create_datagram_endpoint(lambda: self, sock=sock)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def snapshot(self) -> dict[str, Any]:
        out = super().snapshot()
        if self.mutes:  # once muted: whether it is now, how often, what it was spared (see the module doc)
            out.update(muted=self.muted, mutes=self.mutes, muted_dropped=self.muted_dropped, probes=self.probes)
        return out

    # -- receiving ---------------------------------------------------------------
    def datagram_received(self, data: bytes, addr: tuple[str, int] | Any) -> None:
        self._arrived(data, addr, time.monotonic(), len(data))

    def _arrived(self, data: bytes | None, addr: tuple[str, int] | Any, rx_s: float, size: int) -> None:
        """One datagram of ``size`` bytes from ``addr`` (``data`` None: longer than the fast path reads)."""
        self.rx += 1
        if data is None or size > MAX_DATAGRAM_BYTES:  # first: it can neither be split nor become the peer
            self._fault("oversize", f"{size}-byte datagram from {_fmt(addr)} dropped unread "
                                    f"(more than {MAX_DATAGRAM_BYTES} bytes is not MAVLink)")  # fmt: skip
            return
        if addr == self.peer:  # the common case, both modes: the peer we know
            self._peer_heard_s = rx_s
            if self.muted:
                self._resume("the peer sent a datagram")
        elif self._udpin:
            if self.peer is not None:
                if rx_s - self._peer_heard_s < self.takeover_after_s:
                    self._fault("stranger", f"datagram from {_fmt(addr)} while {_fmt(self.peer)} is the peer")
                    return
                self.faults["peer_changed"] += 1
                log.info("endpoint.peer_changed",
                         extra={"endpoint": self.name, "old": _fmt(self.peer), "new": _fmt(addr)})  # fmt: skip
                self._reported.discard("stranger")  # a new peer: strangers to it are news again
            self.peer = addr
            self._peer_heard_s = rx_s
            if self.muted:
                self._resume("the peer sent a datagram")
        else:
            # A udpout socket is not connected (so a vanished peer cannot make it unusable); anything
            # from a stranger is not ours to forward.
            self._fault("foreign_sender", f"datagram from {_fmt(addr)}, expected {_fmt(self.peer)}")
            return
        if self._reported:
            self._reported.discard("unreachable")
        if self._gated_in:
            self._deliver(data, rx_s)
        elif self.receiver is not None:
            self.receiver(data, rx_s)

    def error_received(self, exc: Exception) -> None:
        """ICMP errors (a ground client that closed its port): count, mute the peer, keep the socket."""
        self._drain_errors()
        if isinstance(exc, ConnectionRefusedError) or getattr(exc, "errno", None) == errno.ECONNREFUSED:
            self.faults["unreachable"] += 1
            self._refused_s = time.monotonic()
            if not self.muted:
                self.muted = True
                self.mutes += 1
                log.warning("endpoint.muted", extra={"endpoint": self.name, "url": str(self.endpoint),
                                                     "peer": _fmt(self.peer), "detail": str(exc),
                                                     "probe_every_s": PROBE_INTERVAL_S})  # fmt: skip
            return
        self._fault("socket_error", str(exc))

    def _drain_errors(self) -> list[int]:
        """Empty the kernel's error queue; the errnos it held. Each ICMP error waits there until read, keeps
        the socket flagged (an epoll loop would spin on it) and takes receive-buffer room from real datagrams."""
        sock = self._raw
        found: list[int] = []
        if sock is None or sock.fileno() < 0 or not hasattr(socket, "MSG_ERRQUEUE"):
            return found
        for _ in range(4096):  # bounded: the queue is at most a receive buffer's worth
            try:
                _data, anc, _flags, _addr = sock.recvmsg(1, 512, socket.MSG_ERRQUEUE)
            except OSError:
                return found
            # struct sock_extended_err starts with the errno (native byte order)
            found.extend(int.from_bytes(d[:4], sys.byteorder) for _lvl, _typ, d in anc if len(d) >= 4)
        return found

    def _resume(self, why: str) -> None:
        self.muted = False
        log.info("endpoint.resumed", extra={"endpoint": self.name, "url": str(self.endpoint), "peer": _fmt(self.peer),
                                            "detail": why, "muted_dropped": self.muted_dropped})  # fmt: skip

    def _send_allowed(self, now: float) -> bool:
        """While muted: whether this datagram goes out (a probe, or the probe before it drew no ICMP error).

        False: it is dropped and counted in ``muted_dropped`` by the caller's count ``n``."""
        if self._refused_s < self._probe_s <= now - PROBE_CONFIRM_S:
            self._resume(f"no ICMP error within {PROBE_CONFIRM_S:g} s of a probe")
            return True
        if now - self._probe_s >= PROBE_INTERVAL_S:
            self._probe_s = now
            self.probes += 1
            return True
        return False

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            log.warning("endpoint.lost", extra={"endpoint": self.name, "error": str(exc)})

    # -- sending -----------------------------------------------------------------
    def _write(self, data: bytes) -> bool:
        """Send one datagram to the peer; False (counted) when there is none yet or the socket is backed up."""
        transport = self._transport
        if transport is None or self.peer is None:
            self._fault("no_peer", "nobody has sent to this udpin endpoint yet; dropping until someone does")
            return False
        if self.muted and not self._send_allowed(time.monotonic()):
            self.muted_dropped += 1
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


async def resolve(ep: Endpoint, socktype: int, name: str) -> tuple[int, tuple[Any, ...]]:
    """``(family, sockaddr)`` of the endpoint's host, IPv4 first (``localhost`` is 127.0.0.1, not ::1)."""
    loop = asyncio.get_running_loop()
    try:
        infos = await loop.getaddrinfo(ep.host, ep.port, type=socktype)
    except socket.gaierror as exc:
        raise EndpointError(exc.errno, f"{name} {ep}: cannot resolve {ep.host!r}: {exc.strerror}") from None
    infos.sort(key=lambda info: info[0] != socket.AF_INET)
    family, _, _, _, addr = infos[0]
    return family, tuple(addr)


def _reports_icmp(loop: asyncio.AbstractEventLoop) -> bool:
    """Whether to ask the kernel for ICMP errors on this unconnected socket (``IP_RECVERR``, Linux).

    Then a ground client that went away shows up as ``unreachable`` (counted,
    logged once) instead of nothing. Only on the standard loop: uvloop 0.2x
    crashes (SIGSEGV) on the second such error, so under uvloop a vanished
    peer stays silent; forwarding is the same either way.
    """
    return type(loop).__module__.startswith("asyncio") and sys.platform == "linux"


def _fmt(addr: Any) -> str:
    """``host:port`` of a socket address; a serial device's path as it is."""
    if addr is None:
        return "-"
    return addr if isinstance(addr, str) else f"{addr[0]}:{addr[1]}"

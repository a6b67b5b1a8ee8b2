"""UDP endpoints on the compiled fast path (``mitm_proxy/net/_fastpath.c``; mitm_proxy/README.md, "The fast path").

A :class:`NativeUdpEndpoint` reads its socket itself (``loop.add_reader``) and hands each batch to the
C route: datagrams from the pinned peer that are nothing but valid frames nobody wants are sent on, byte
for byte, to the link's other side with ``sendmmsg`` and counted; every other datagram comes back here, in
order, and takes the pure-Python path (:meth:`UdpEndpoint._arrived`, the link, the pipeline) unchanged.

Who wants what is Python's to say: before each batch the endpoint asks the link's pipeline
(:meth:`Pipeline.fast_wanted`: the message ids of the active stages and the field filters narrowing some
of them, e.g. an attack on a few DISTANCE_SENSOR sensor ids leaves the other sensors' frames in C; or None
while an observer, a signing key or a sequence watch needs every frame), its own inbound rules and the
targets' outbound rules, and reconfigures the route when that changed. A profile swap, a stage switched
off, a recorder attached or a route rule set therefore take effect from the next batch on, as they do
between two datagrams on the Python path.

A frame the stages want may still stay in C: for the ids the pipeline lets the route repeat (``memo`` of
:class:`~mitm_proxy.core.pipeline.FastWants`), each endpoint registers its route's ``learn`` with the pipeline;
after Python rewrote such a frame, the route remembers it and rewrites later frames with the same key itself
(counted as the pipeline counts them), until the stage's time is up. A new token (another profile, a restarted
clock) makes it forget everything (mitm_proxy/README.md, "The fast path").

``SECUAV_PROXY_PYTHON=1`` in the environment (or a build without a C compiler) gives the pure-Python
endpoints (:func:`enabled`).
"""

from __future__ import annotations

import asyncio
import errno
import os
import select
import socket
import sys
import time
from array import array
from collections import deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from mavframe.codec import MAVLINK_MAP
from mavframe.frames import CRC_EXTRA
from mavframe.packet import Direction
from mitm_proxy.net.endpoints import MAX_PENDING_SEND_BYTES, BaseEndpoint, UdpEndpoint, _reports_icmp

if TYPE_CHECKING:
    from mitm_proxy.net.link import Link

try:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]
except ImportError:  # not built (no C compiler at install time, or not Linux/macOS): the Python path
    _fastpath = None

__all__ = ["FORCE_PYTHON_ENV", "NativeUdpEndpoint", "available", "enabled", "filter_specs", "id_bits", "memo_specs",
           "route_wants"]

FORCE_PYTHON_ENV = "SECUAV_PROXY_PYTHON"
_IDS = 65536  # the route's id bitmap; higher ids are never forwarded by it (none is in the dialect)


def available() -> bool:
    """Whether the compiled part is installed."""
    return _fastpath is not None


def enabled() -> bool:
    """Whether new UDP endpoints take the fast path: built, and not turned off by ``SECUAV_PROXY_PYTHON``."""
    return _fastpath is not None and os.environ.get(FORCE_PYTHON_ENV, "").strip().lower() in ("", "0", "false", "no")


def id_bits(ids: frozenset[int] | set[int]) -> bytes:
    """The route's bitmap of message ids (bit ``id`` set for each id below 65536)."""
    bits = bytearray(_IDS // 8)
    for msgid in ids:
        if 0 <= msgid < _IDS:
            bits[msgid >> 3] |= 1 << (msgid & 7)
    return bytes(bits)


_NONE = id_bits(frozenset())


def route_wants(ids: frozenset[int], filters: dict[int, tuple[int, frozenset[int]]],
                memo: dict[int, tuple[int, int]] | None = None) -> tuple[bytes, list[Any], list[Any]]:  # fmt: skip
    """What the route takes for the pipeline's wanted ids, field filters and memo ids (:meth:`Pipeline.fast_wanted`):
    the bitmap of the ids wanted whole, the filters (:func:`filter_specs`) and the memo ids (:func:`memo_specs`);
    beyond the route's ``MAX_FILTERS``, the ids of the last filters are wanted whole, and beyond ``MAX_MEMO_IDS``
    the last memo ids always go up."""
    if len(filters) > _fastpath.MAX_FILTERS:
        filters = dict(sorted(filters.items())[: _fastpath.MAX_FILTERS])
    whole = ids - filters.keys() if filters else ids  # a filtered id is the filter's to decide
    return id_bits(whole), filter_specs(filters), memo_specs(memo or {})


def memo_specs(memo: dict[int, tuple[int, int]]) -> list[tuple[int, int, int]]:
    """The ids whose rewrites the route may repeat (``msgid -> (offset, length)`` of the payload span their key
    leaves out) as the route takes them: ``(msgid, offset, length)``, ids in order, at most ``MAX_MEMO_IDS``."""
    return [(msgid, off, n) for msgid, (off, n) in sorted(memo.items())[: _fastpath.MAX_MEMO_IDS]]


def filter_specs(filters: dict[int, tuple[int, frozenset[int]]]) -> list[tuple[int, int, bytes]]:
    """The pipeline's field filters (``msgid -> (payload offset, values)``) as the route takes them:
    ``(msgid, offset, 32-byte bitmap of the values)``, ids in order."""
    out = []
    for msgid, (offset, values) in sorted(filters.items()):
        bits = bytearray(32)
        for v in values:
            bits[v >> 3] |= 1 << (v & 7)
        out.append((msgid, offset, bytes(bits)))
    return out


def _load_dialect() -> None:
    extra = bytearray(_IDS)
    for msgid, value in CRC_EXTRA.items():
        if msgid < _IDS:
            extra[msgid] = value
    v1_max = bytearray(256)
    for msgid, cls in MAVLINK_MAP.items():
        if msgid < 256:
            v1_max[msgid] = min(255, cls.unpacker.size)
    _fastpath.set_dialect(bytes(extra), id_bits(frozenset(CRC_EXTRA)), bytes(v1_max))


if _fastpath is not None:
    _load_dialect()


class _Binding:
    """The link an endpoint feeds and where that direction's frames go (set by the link)."""

    __slots__ = ("direction", "link", "receiver", "targets")

    def __init__(self, receiver: Callable[[bytes, float], None], link: Link, direction: Direction,
                 targets: Sequence[BaseEndpoint]) -> None:  # fmt: skip
        self.receiver = receiver
        self.link = link
        self.direction = direction
        self.targets = tuple(targets)


class NativeUdpEndpoint(UdpEndpoint):
    """A UDP endpoint whose socket the fast path reads and writes (see the module doc)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._sock: socket.socket | None = None
        self._epoll: select.epoll | None = None
        self._fd = -1
        self._family = socket.AF_INET
        self._loop: asyncio.AbstractEventLoop | None = None
        self._route: Any = None
        self._binding: _Binding | None = None
        self._state: Any = ()  # what the route was last configured with (never equal to a real state)
        self._token: Any = ()  # what the route's memory was learnt under (FastWants.token)
        self._targets: tuple[NativeUdpEndpoint, ...] = ()
        self._skipped: tuple[NativeUdpEndpoint, ...] = ()  # muted targets the route leaves out
        self.fast_datagrams = 0  # received datagrams the route forwarded without Python
        self.fast_rewritten = 0  # frames among them the route rewrote from its memory
        # Datagrams the kernel would not take at once, sent when the socket is writable again (as asyncio's
        # transport does): up to MAX_PENDING_SEND_BYTES, beyond that dropped and counted (send_overflow).
        self._backlog: deque[bytes] = deque()
        self._backlog_bytes = 0
        self.queued = 0  # datagrams that waited in that queue

    def _wants_icmp(self, loop: asyncio.AbstractEventLoop) -> bool:
        # This endpoint reads its socket itself (no loop transport to trip up): a ground peer nobody listens on
        # is seen on every loop, and muted (endpoints module doc). Under uvloop that takes an epoll of its own
        # (see _start), one more system call per wake-up: a ground socket wakes for uplink, a few frames a
        # second, while the vehicle's socket wakes for all the telemetry, so only ground sockets pay it there.
        return sys.platform == "linux" and (self.role == "ground" or _reports_icmp(loop))

    async def _start(self, loop: asyncio.AbstractEventLoop, sock: socket.socket, family: int) -> None:
        self._sock, self._fd, self._family, self._loop = sock, sock.fileno(), family, loop
        self._route = _fastpath.Route(self._fd)
        if _reports_icmp(loop) or not self._wants_icmp(loop) or not hasattr(select, "epoll"):
            loop.add_reader(self._fd, self._readable)
        else:
            # libuv (uvloop) stops watching a socket that reports an error (POLLERR: a queued ICMP error) and
            # would never read it again; behind an epoll of its own the loop only ever sees that epoll readable.
            self._epoll = select.epoll()
            self._epoll.register(self._fd, select.EPOLLIN)
            loop.add_reader(self._epoll.fileno(), self._on_epoll)

    def close(self) -> None:
        if self._sock is None:
            return
        if self._loop is not None and not self._loop.is_closed():
            if self._epoll is not None:
                self._loop.remove_reader(self._epoll.fileno())
            else:
                self._loop.remove_reader(self._fd)
                if self._backlog:
                    self._loop.remove_writer(self._fd)
        if self._epoll is not None:
            self._epoll.close()
            self._epoll = None
        self._backlog.clear()
        self._backlog_bytes = 0
        self._sock.close()
        self._sock = self._route = None
        if self._binding is not None:
            _unlearn(self._binding, self._learn)

    def snapshot(self) -> dict[str, Any]:
        out = super().snapshot()
        out["fast"] = {"datagrams": self.fast_datagrams, "rewritten": self.fast_rewritten}
        return out

    def bind_fast(self, receiver: Callable[[bytes, float], None], link: Link, direction: Direction,
                  targets: Sequence[BaseEndpoint]) -> None:  # fmt: skip
        """What arrives here goes to ``link`` as ``direction`` and leaves through ``targets`` (the link calls it
        when ``receiver`` is its own; while the endpoint's receiver is something else, nothing takes the fast path)."""
        old = self._binding
        if old is not None:
            _unlearn(old, self._learn)
        self._binding = _Binding(receiver, link, direction, targets)
        self._state = ()
        link.pipeline.learners.setdefault(direction, []).append(self._learn)

    def _learn(self, frame: bytes, out: bytes, until_s: float, counted: bool) -> None:
        """The pipeline rewrote ``frame`` into ``out``, and may be repeated until ``until_s``: the route keeps it
        (only while the route is on, for the memo ids it was configured with; it checks the rest)."""
        if self._route is not None and self._state:
            self._route.learn(frame, out, until_s, counted)

    # -- sending (the Python path's datagrams) -------------------------------------------------------
    def _write(self, data: bytes) -> bool:
        """Send one datagram to the peer (queued behind others the kernel has not taken yet)."""
        sock = self._sock
        if sock is None or self.peer is None:
            self._fault("no_peer", "nobody has sent to this udpin endpoint yet; dropping until someone does")
            return False
        if self.muted and not self._send_allowed(time.monotonic()):
            self.muted_dropped += 1
            return False
        if self._backlog:
            return self._queue((data,))
        try:
            sock.sendto(data, self.peer)
        except BlockingIOError:
            return self._queue((data,))
        except OSError as exc:  # an ICMP error reported on this send (IP_RECVERR), or the like
            self.error_received(exc)
            return False
        self.tx += 1
        if self._reported:
            self._reported.discard("no_peer")
        return True

    def _queue(self, datagrams: Sequence[bytes]) -> bool:
        """Keep what the kernel would not take, in order, until the socket is writable; False if over the bound."""
        queued = False
        for data in datagrams:
            if self._backlog_bytes > MAX_PENDING_SEND_BYTES:
                self._fault("send_overflow", f"more than {MAX_PENDING_SEND_BYTES} bytes waiting to be sent")
                continue
            if not self._backlog:
                self._want_write(True)
            self._backlog.append(data)
            self._backlog_bytes += len(data)
            self.queued += 1
            self.tx += 1
            queued = True
        return queued

    def _flush(self) -> None:
        sock, backlog = self._sock, self._backlog
        while backlog and sock is not None and self.peer is not None:
            try:
                sock.sendto(backlog[0], self.peer)
            except BlockingIOError:
                return
            except OSError as exc:
                self.error_received(exc)
            self._backlog_bytes -= len(backlog.popleft())
        backlog.clear()
        self._backlog_bytes = 0
        self._want_write(False)

    def _want_write(self, on: bool) -> None:
        """Call :meth:`_flush` when the socket is writable (on), or no more (off)."""
        if self._epoll is not None:
            self._epoll.modify(self._fd, select.EPOLLIN | (select.EPOLLOUT if on else 0))
        elif self._loop is not None and not self._loop.is_closed():
            if on:
                self._loop.add_writer(self._fd, self._flush)
            else:
                self._loop.remove_writer(self._fd)

    def _on_epoll(self) -> None:
        """The socket's own epoll is readable (uvloop): an ICMP error, datagrams, or room to send."""
        ep = self._epoll
        if ep is None:
            return
        for _fd, events in ep.poll(0):
            if events & select.EPOLLERR and errno.ECONNREFUSED in self._drain_errors():
                self.error_received(ConnectionRefusedError(errno.ECONNREFUSED, os.strerror(errno.ECONNREFUSED)))
            if events & select.EPOLLOUT and self._backlog:
                self._flush()
            if events & (select.EPOLLIN | select.EPOLLERR):
                self._readable()

    # -- receiving -------------------------------------------------------------------------------------
    def _fast_state(self) -> tuple[Any, ...] | None:
        """What the route needs now: ``(peer, FastWants, targets and their peers, muted targets left out)``, or
        None: all up."""
        b = self._binding
        if b is None or self.receiver is not b.receiver or self.peer is None or self._gated_in or not b.targets:
            return None
        ids = b.link.pipeline.fast_wanted(b.direction)
        if ids is None:
            return None
        targets = []
        skipped = []
        now = 0.0
        eps: list[NativeUdpEndpoint] = []
        for ep in b.targets:
            if not isinstance(ep, NativeUdpEndpoint) or ep._sock is None or ep.peer is None or ep._gated_out:
                return None
            if ep._backlog:  # its queue goes first: Python sends behind it until it is empty
                return None
            eps.append(ep)
        for ep in eps:  # all can take the route: only now may a muted one's probe be spent on it
            if ep.muted:  # nobody listens there: left out, but for a probe now and then (endpoints module doc)
                now = now or time.monotonic()
                if not ep._send_allowed(now):
                    skipped.append(ep)
                    continue
            targets.append((ep, ep.peer))
        return self.peer, ids, tuple(targets), tuple(skipped)

    def _configure(self) -> None:
        state = self._fast_state()
        if state == self._state:
            return
        self._state = state
        if state is None:
            self._targets = self._skipped = ()
            self._route.configure(True, self._family, None, (), _NONE, ())
            return
        peer, wants, targets, self._skipped = state
        self._targets = tuple(ep for ep, _ in targets)
        if wants.token != self._token:  # another profile or a restarted clock: what was learnt may not hold
            self._token = wants.token
            self._route.forget()
        self._route.configure(False, self._family, peer, [(ep._fd, ep._family, p) for ep, p in targets],
                              *route_wants(wants.ids, wants.filters, wants.memo))  # fmt: skip

    def _readable(self) -> None:
        route = self._route
        if route is None:
            return
        self._configure()
        hist = None
        b = self._binding
        if b is not None:
            hist = b.link.stats.latency_hist
        counts = hist._counts if hist is not None else array("q")
        while self._route is route:  # handling a datagram may close the endpoint
            res = route.drain(counts)
            if res is None:  # nothing left to read
                return
            if isinstance(res, int):  # the socket reported an error (an ICMP error, with IP_RECVERR)
                self.error_received(OSError(res, os.strerror(res)))
                return
            dgrams, frames, nbytes, nbytes_out, signed, rewritten, rx_s, lat_s, sent, errs, unsent, up, more = res
            if dgrams:
                self._account(dgrams, frames, nbytes, nbytes_out, signed, rewritten, rx_s, lat_s, sent, errs, unsent)
            if up is not None:
                self._arrived(*up)
                if more:  # handling it may have changed what is wanted (a stage, a peer): ask again
                    self._configure()
            if not more:
                return

    def _account(self, dgrams: int, frames: int, nbytes: int, nbytes_out: int, signed: int, rewritten: int,
                 rx_s: float, lat_s: float, sent: tuple[int, ...], errs: tuple[int, ...],
                 unsent: tuple[list[bytes] | None, ...]) -> None:  # fmt: skip
        """Count what the route forwarded (and rewrote) as the Python path counts it (pipeline, link and endpoints)."""
        b = self._binding
        assert b is not None
        st = b.link.pipeline.stats.directions[b.direction]
        st.datagrams_in += dgrams
        st.frames_in += frames
        st.bytes_in += nbytes
        st.frames_out += frames
        st.bytes_out += nbytes_out
        if signed:
            st.signed += signed
        if rewritten:
            st.rewritten += rewritten
            self.fast_rewritten += rewritten
        hist = b.link.stats.latency_hist
        hist.count += dgrams
        if lat_s > hist.max_s:
            hist.max_s = lat_s
        self.rx += dgrams
        self.fast_datagrams += dgrams
        self._peer_heard_s = rx_s
        if self.muted:
            self._resume("the peer sent a datagram")
        if self._reported:
            self._reported.discard("unreachable")
        for ep in self._skipped:
            ep.muted_dropped += dgrams
        for ep, n, err, rest in zip(self._targets, sent, errs, unsent, strict=True):
            ep.tx += n
            if n and ep._reported:
                ep._reported.discard("no_peer")
            if err:
                ep.error_received(OSError(err, os.strerror(err)))
            if rest:
                ep._queue(rest)
        if any(unsent):
            self._configure()  # a target has a queue now: the rest of the batch goes through Python, behind it


def _unlearn(binding: _Binding, learn: Callable[..., None]) -> None:
    """Take an endpoint's ``learn`` back from the pipeline it was registered with."""
    found = binding.link.pipeline.learners.get(binding.direction)
    if found is not None and learn in found:
        found.remove(learn)

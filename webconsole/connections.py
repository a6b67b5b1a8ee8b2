"""How the console is served: uvicorn, behind limits that keep one client from locking the operator out.

uvicorn alone keeps a connection that sends half a request for ever, and
accepts until the process runs out of file descriptors (then logs a traceback
per failed accept). :func:`server_config` serves the app with the guards of
this module (docs/security.md, "The console"):

- **Connections per address and in all**: a connection past
  ``per_address`` from one address, or past ``total``, is closed as soon as it
  is accepted. A ``--trusted-proxy`` forwards for everyone behind it, so its own
  address counts only against the total.
- **Read timeouts**: a connection that has no request in progress (just
  connected, or between requests) must complete a request's headers within
  ``header_timeout_s``, or it is closed: a half-sent request (slowloris) holds
  its descriptor that long and no longer. A request's body is read within
  ``webconsole.api.BODY_TIMEOUT_S`` (else 408).
- **Forwarded headers** (``X-Forwarded-For``, ``X-Forwarded-Proto``) are read
  only from the addresses given with ``--trusted-proxy``; from anyone else they
  are ignored, so a client cannot pick the address its password failures and
  stream slots are counted against.
- **Quiet refusals**: refusals, timeouts and failed accepts are logged at most
  once per 10 s per kind, with the count (``console.connection_refused`` ...).
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import logging
import resource
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import uvicorn
from starlette.types import ASGIApp
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.protocols.utils import get_remote_addr

from secuav_common.logs import RateLimitedLog

log = logging.getLogger("secuav-console")

MAX_CONNECTIONS = 256  # well under the descriptor limit (raised to its hard cap at start, see raise_file_limit)
MAX_CONNECTIONS_PER_ADDRESS = 32  # a browser opens 6 per host, plus 4 event streams; a few tabs and scripts
HEADER_TIMEOUT_S = 10.0
# Connections accepted per turn of the loop (and the kernel's queue): each batch is admitted or refused, closing
# its descriptors, before the next is taken, so a burst does not run even a 1024-descriptor process out of them
# (then asyncio stops accepting for a second). Measured with benchmarks/lockout_bench.py --cases slowloris:
# 2048 (uvicorn's default) answered the operator in ~1 s, 128 in 18 ms to 1 s (a full queue drops the SYN), 512
# in 86-146 ms.
BACKLOG = 512
ACCEPT_ERRORS = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


@dataclass(frozen=True)
class ConnectionLimits:
    per_address: int = MAX_CONNECTIONS_PER_ADDRESS
    total: int = MAX_CONNECTIONS
    header_timeout_s: float = HEADER_TIMEOUT_S


class ConnectionGuard:
    """Open connections per address and in all, and the rate-limited log of what was refused."""

    def __init__(self, limits: ConnectionLimits, trusted: Iterable[str] = ()) -> None:
        self.limits = limits
        self.trusted = [ipaddress.ip_network(t, strict=False) for t in trusted]
        self.open: Counter[str] = Counter()
        self.events = RateLimitedLog(log)

    def is_trusted(self, address: str) -> bool:
        try:
            ip = ipaddress.ip_address(address)
        except ValueError:
            return False
        return any(ip in net for net in self.trusted)

    def admit(self, address: str) -> str | None:
        """Count a new connection from ``address``; returns why not (and counts nothing), or None."""
        if sum(self.open.values()) >= self.limits.total:
            return f"{self.limits.total} connections are open, the most this console serves"
        if self.open[address] >= self.limits.per_address and not self.is_trusted(address):
            return f"{self.limits.per_address} connections are open from {address}, the most one address may hold"
        self.open[address] += 1
        return None

    def release(self, address: str) -> None:
        self.open[address] -= 1
        if self.open[address] <= 0:
            del self.open[address]


def guarded_protocol(guard: ConnectionGuard) -> type[H11Protocol]:
    """uvicorn's HTTP/1.1 protocol with :class:`ConnectionGuard`'s caps and the header read timeout."""
    timeout_s = guard.limits.header_timeout_s

    class GuardedH11(H11Protocol):
        _address: str | None = None
        _check: asyncio.TimerHandle | None = None
        _waiting_since: float | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            remote = get_remote_addr(transport)
            address = remote[0] if remote else "?"
            refused = guard.admit(address)
            if refused is not None:
                guard.events.event("console.connection_refused", client=address, reason=refused)
                transport.abort()
                return
            self._address = address
            super().connection_made(transport)
            self._waiting_since = time.monotonic()
            self._check = self.loop.call_later(timeout_s / 2, self._check_reading)

        def _check_reading(self) -> None:
            """A connection with no request in progress must finish one's headers in ``timeout_s``."""
            if self.transport is None or self.transport.is_closing():
                return
            busy = self.cycle is not None and not self.cycle.response_complete
            now = time.monotonic()
            if busy:
                self._waiting_since = None
            elif self._waiting_since is None:
                self._waiting_since = now
            elif now - self._waiting_since >= timeout_s:
                guard.events.event("console.read_timeout", client=self._address,
                                   detail=f"no complete request headers within {timeout_s:g} s; closed")  # fmt: skip
                self.transport.close()
                return
            self._check = self.loop.call_later(timeout_s / 2, self._check_reading)

        def data_received(self, data: bytes) -> None:
            if self._address is not None:
                super().data_received(data)

        def connection_lost(self, exc: Exception | None) -> None:
            if self._address is None:
                return
            guard.release(self._address)
            self._address = None
            if self._check is not None:
                self._check.cancel()
            super().connection_lost(exc)

    return GuardedH11


def server_config(app: ASGIApp, host: str, port: int, *, trusted_proxies: Iterable[str] = (),
                  limits: ConnectionLimits | None = None, **options: Any) -> uvicorn.Config:  # fmt: skip
    """The uvicorn configuration ``secuav-console`` serves ``app`` with (``options``: TLS files and the like)."""
    trusted = list(trusted_proxies)
    guard = ConnectionGuard(limits or ConnectionLimits(), trusted)
    return uvicorn.Config(app, host=host, port=port, http=guarded_protocol(guard), log_level="warning",
                          access_log=False, lifespan="off", proxy_headers=bool(trusted),
                          forwarded_allow_ips=trusted or None, backlog=BACKLOG, **options)  # fmt: skip


def quiet_accept_errors(loop: asyncio.AbstractEventLoop) -> RateLimitedLog:
    """Failed accepts (out of descriptors) as one counted line per 10 s instead of a traceback each."""
    events = RateLimitedLog(log)
    default = loop.get_exception_handler()

    def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if isinstance(exc, OSError) and exc.errno in ACCEPT_ERRORS:
            events.event("console.accept_failed", error=exc.strerror or str(exc))
        elif default is not None:
            default(loop, context)
        else:
            loop.default_exception_handler(context)

    loop.set_exception_handler(handler)
    return events


def raise_file_limit() -> int:
    """Raise this process's descriptor limit to its hard cap (what the connection caps are measured against)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return soft

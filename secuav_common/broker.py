"""MQTT broker URLs and an embedded amqtt broker for the control plane.

``secuav-proxy --broker embedded`` (and the demos, and tests) run an amqtt
broker inside the process, bound to loopback. If something already listens on
the port (a mosquitto, or another SecUAV process's embedded broker) we use that
instead of failing, so two SecUAV processes can share one control plane.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from urllib.parse import urlsplit

from secuav_common.loading import InputError
from secuav_common.ports import LOOPBACK, MQTT_PORT

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class BrokerAddress:
    host: str
    port: int
    username: str | None = None
    password: str | None = None
    tls: bool = False

    @property
    def url(self) -> str:
        scheme = "mqtts" if self.tls else "mqtt"
        return f"{scheme}://{self.host}:{self.port}"


def parse_broker_url(url: str) -> BrokerAddress:
    """Parse ``mqtt://[user:pass@]host[:port]`` or ``mqtts://...``; ``ValueError`` names the bad part."""
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts"):
        raise ValueError(f"broker {url!r}: scheme must be mqtt:// or mqtts://")
    if not parts.hostname:
        raise ValueError(f"broker {url!r}: missing host")
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"broker {url!r}: bad port") from None
    tls = parts.scheme == "mqtts"
    return BrokerAddress(parts.hostname, port or (8883 if tls else MQTT_PORT), parts.username, parts.password, tls)


def redact(url: str) -> str:
    """``url`` with any password replaced by ``***``, for logs (``mqtt://op:***@host:1883``)."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.replace(f":{parts.password}@", ":***@", 1)
    return parts._replace(netloc=netloc).geturl()


def read_secret(path: str | Path, what: str) -> bytes:
    """A secret from a file that only its owner can read (as ssh demands of a private key); ``InputError`` else."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(str(p), what, str(path), f"cannot read: {exc.strerror or exc}") from None
    if mode & 0o077:
        reason = f"readable by others (mode {oct(mode & 0o777)}); chmod 600 it, as ssh demands of a private key"
        raise InputError(str(p), what, str(path), reason)
    return data


def port_in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(0.2)
        return sock.connect_ex((host, port)) == 0


class EmbeddedBroker:
    """``async with EmbeddedBroker(port=1883) as broker: ... broker.address``.

    Starts amqtt on ``host:port`` unless a broker already answers there, in
    which case it is reused (``broker.started`` is then False).
    """

    def __init__(self, host: str = LOOPBACK, port: int = MQTT_PORT) -> None:
        self.address = BrokerAddress(host, port)
        self.started = False
        self._broker: object | None = None

    async def __aenter__(self) -> EmbeddedBroker:
        if port_in_use(self.address.host, self.address.port):
            # Someone else's broker (another proxy's, a mosquitto): it works, but it may not be the one meant.
            log.warning("broker.reuse", extra={
                "url": self.address.url,
                "detail": "a broker already listens here and is used as it is (not started by this process); "
                "give --broker mqtt://HOST:PORT to choose one",
            })  # fmt: skip
            return self
        from amqtt.broker import Broker  # imported lazily: only the embedding process needs it

        # amqtt warns for every client that connects and leaves without a CONNECT
        # (our own port probe, health checks); that is not worth a line.
        for name in ("amqtt", "transitions"):
            logging.getLogger(name).setLevel(logging.ERROR)
        config = {
            "listeners": {"default": {"type": "tcp", "bind": f"{self.address.host}:{self.address.port}"}},
            "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
        }
        broker = Broker(config)
        await broker.start()
        self._broker = broker
        self.started = True
        log.info("broker.started", extra={"url": self.address.url})
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._broker is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._broker.shutdown(), timeout=3.0)  # type: ignore[attr-defined]
            self._broker = None

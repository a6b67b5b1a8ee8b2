"""Where the broker is: ``mqtt://[user:pass@]host[:port]`` or ``mqtts://...`` (TLS, port 8883 by default)."""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import urlsplit

from secuav_common.ports import MQTT_PORT


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


def with_port(url: str, port: int | None) -> str:
    """``url`` (``mqtt://...``) moved to ``port`` (``--broker-port``); ``ValueError`` if it names another port."""
    if port is None:
        return url
    if not 0 < port < 65536:
        raise ValueError(f"--broker-port {port}: outside 1..65535")
    parts = urlsplit(url)
    try:
        given = parts.port
    except ValueError:
        raise ValueError(f"broker {url!r}: bad port") from None
    if given is not None and given != port:
        raise ValueError(f"broker {redact(url)!r} names port {given} but --broker-port says {port}: give one")
    host = parts.netloc.rpartition("@")[2].rsplit(":", 1)[0] if given is not None else parts.netloc.rpartition("@")[2]
    userinfo = parts.netloc.rpartition("@")[0]
    netloc = (f"{userinfo}@" if userinfo else "") + f"{host}:{port}"
    return parts._replace(netloc=netloc).geturl()

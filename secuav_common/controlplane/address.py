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

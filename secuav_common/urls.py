"""MAVLink endpoint URLs as MAVSDK and mavlink-router write them.

``udpin://HOST:PORT`` binds HOST:PORT and answers the peer that sent first (another sender takes its
place only after that peer fell silent, see mitm_proxy.endpoints);
``udpout://HOST:PORT`` sends to a fixed peer from an ephemeral port.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True, slots=True)
class Endpoint:
    mode: Literal["udpin", "udpout"]
    host: str
    port: int

    @property
    def address(self) -> tuple[str, int]:
        return (self.host, self.port)

    def __str__(self) -> str:
        return f"{self.mode}://{self.host}:{self.port}"


def parse_endpoint(url: str) -> Endpoint:
    """Parse ``udpin://host:port`` / ``udpout://host:port``; ``ValueError`` names the bad part."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        raise ValueError(f"endpoint {url!r}: expected udpin://HOST:PORT or udpout://HOST:PORT")
    if scheme not in ("udpin", "udpout"):
        raise ValueError(f"endpoint {url!r}: scheme {scheme!r} is not supported (udpin, udpout)")
    host, colon, port_text = rest.rpartition(":")
    if not colon or not host:
        raise ValueError(f"endpoint {url!r}: missing HOST:PORT")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"endpoint {url!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"endpoint {url!r}: port {port} outside 0..65535")
    return Endpoint(scheme, host.strip("[]"), port)  # type: ignore[arg-type]

"""MAVLink endpoint URLs as MAVSDK, mavlink-router and mavutil write them.

``udpin://HOST:PORT`` binds HOST:PORT and answers the peer that sent first (another sender takes its
place only after that peer fell silent, see mitm_proxy.net.endpoints);
``udpout://HOST:PORT`` sends to a fixed peer from an ephemeral port;
``tcp://HOST:PORT`` connects to a MAVLink TCP server (ArduPilot SITL's 5760) and reconnects when it goes
or falls silent for 10 s;
``tcpin://HOST:PORT`` is a TCP server: every client that connects is a peer, up to ``max_clients`` of them
(``tcpin://0.0.0.0:5760?max_clients=4``; default 16) and up to ``max_clients_per_address`` from one address
(default 4); a client that floods it with bytes that are not MAVLink (over 64 kB a second, counted per
client), reads nothing for 5 s while frames wait, or sends no MAVLink frame within ``idle_s`` seconds of
connecting (default 15; a GCS's 1 Hz HEARTBEAT is one; ``idle_s=0`` for a script that only reads) is disconnected;
``serial:///dev/ttyUSB0?baud=57600`` is a serial port (a telemetry radio).
Every stream is framed a slice at a time, so no peer holds up the others (mitm_proxy.net.tcp_serial).

``udp://`` (MAVSDK's spelling) and mavutil's ``udp:`` mean ``udpin``: they listen. MAVSDK's ``udp://:PORT``
(no host: every interface) is refused with a line that says to write ``udpin://127.0.0.1:PORT`` or, to
listen on every interface on purpose, ``udpin://0.0.0.0:PORT``.
mavutil's spellings are accepted too (``udpin:HOST:PORT``, ``udpout:HOST:PORT``, ``tcp:HOST:PORT``,
``tcpin:HOST:PORT``, ``/dev/ttyUSB0,57600``), and IPv6 literals in brackets
(``udpin://[::1]:14550``). What follows ``?`` is kept as the endpoint's options (``listen_only=true``,
``deny=DISTANCE_SENSOR``; ``mitm_proxy.net.rules`` reads them); ``str()`` gives the canonical URL back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, cast
from urllib.parse import parse_qsl, quote

Mode = Literal["udpin", "udpout", "tcp", "tcpin", "serial"]
MODES: tuple[Mode, ...] = ("udpin", "udpout", "tcp", "tcpin", "serial")
_ALIASES = {"udp": "udpin"}  # MAVSDK's udp:// and mavutil's udp: both listen
DEFAULT_BAUD = 57600  # SiK telemetry radios' default
_EXPECTED = "udpin://HOST:PORT, udpout://HOST:PORT, tcp://HOST:PORT, tcpin://HOST:PORT or serial:///DEV?baud=N"


@dataclass(frozen=True, slots=True)
class Endpoint:
    """One parsed URL; for ``serial`` ``host`` is the device path and ``port`` the baud rate."""

    mode: Mode
    host: str
    port: int
    options: tuple[tuple[str, str], ...] = ()

    @property
    def address(self) -> tuple[str, int]:
        return (self.host, self.port)

    @property
    def is_stream(self) -> bool:
        """TCP and serial carry a byte stream (frames may be cut anywhere), UDP carries datagrams."""
        return self.mode in ("tcp", "tcpin", "serial")

    def option(self, key: str) -> str | None:
        for k, v in self.options:
            if k == key:
                return v
        return None

    def without_options(self) -> Endpoint:
        return Endpoint(self.mode, self.host, self.port)

    def __str__(self) -> str:
        query = "&".join(f"{k}={quote(v, safe=',:')}" for k, v in self.options)
        if self.mode == "serial":
            extra = f"&{query}" if query else ""
            return f"serial://{self.host}?baud={self.port}{extra}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.mode}://{host}:{self.port}" + (f"?{query}" if query else "")


def parse_endpoint(url: str) -> Endpoint:
    """Parse any spelling the module doc lists; ``ValueError`` names the URL and the bad part."""
    text = url.strip()
    base, _, query = text.partition("?")
    try:
        options = tuple(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
    except ValueError:
        raise ValueError(f"endpoint {url!r}: options {query!r} are not KEY=VALUE pairs joined by &") from None
    if base.startswith("/") and "://" not in base:  # mavutil: /dev/ttyUSB0,57600
        device, _, baud = base.partition(",")
        return _serial(url, device, baud or None, options)
    scheme, sep, rest = base.partition("://")
    if not sep:  # mavutil: udpin:HOST:PORT
        scheme, sep, rest = base.partition(":")
        if not sep or scheme not in (*MODES, *_ALIASES):
            raise ValueError(f"endpoint {url!r}: expected {_EXPECTED}")
    scheme = _ALIASES.get(scheme, scheme)
    if scheme not in MODES:
        raise ValueError(f"endpoint {url!r}: scheme {scheme!r} is not supported ({', '.join(MODES)})")
    if scheme == "serial":
        baud_opts = [v for k, v in options if k == "baud"]
        rest_opts = tuple((k, v) for k, v in options if k != "baud")
        return _serial(url, rest, baud_opts[-1] if baud_opts else None, rest_opts)
    host, colon, port_text = rest.rpartition(":")
    if colon and not host and scheme in ("udpin", "tcpin"):  # MAVSDK's udp://:14540 (every interface)
        raise ValueError(f"endpoint {url!r}: give the address to listen on: {scheme}://127.0.0.1:{port_text} "
                         f"(this machine only) or {scheme}://0.0.0.0:{port_text} (every interface, as MAVSDK's "
                         f"udp://:{port_text} means)")  # fmt: skip
    if not colon or not host:
        raise ValueError(f"endpoint {url!r}: missing HOST:PORT")
    if host.startswith("["):
        if not host.endswith("]"):
            raise ValueError(f"endpoint {url!r}: an IPv6 address needs both brackets, as in [::1]:14550")
        host = host[1:-1]
    elif ":" in host:
        raise ValueError(f"endpoint {url!r}: write an IPv6 address in brackets, as in udpin://[::1]:14550")
    if not host:
        raise ValueError(f"endpoint {url!r}: missing HOST")
    port = _number(url, "port", port_text)
    if not 0 <= port <= 65535:
        raise ValueError(f"endpoint {url!r}: port {port} outside 0..65535")
    return Endpoint(cast(Mode, scheme), host, port, options)


def _serial(url: str, device: str, baud: str | None, options: tuple[tuple[str, str], ...]) -> Endpoint:
    if not device.startswith("/") or len(device) < 2:
        raise ValueError(f"endpoint {url!r}: a serial endpoint needs a device path, as in serial:///dev/ttyUSB0")
    rate = DEFAULT_BAUD if baud is None else _number(url, "baud", baud)
    if rate <= 0:
        raise ValueError(f"endpoint {url!r}: baud {rate} must be positive")
    return Endpoint("serial", device, rate, options)


def _number(url: str, what: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"endpoint {url!r}: {what} {text!r} is not a number") from None

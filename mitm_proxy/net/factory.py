"""The endpoint for a URL: ``udpin``/``udpout`` -> UDP, ``tcp``/``tcpin``/``serial`` -> the byte-stream endpoints.

Beside both families, so neither imports the other: :mod:`~mitm_proxy.net.endpoints` (the base class and
UDP) and :mod:`~mitm_proxy.net.tcp_serial` (TCP client and server, serial port).
"""

from __future__ import annotations

from mitm_proxy.net import native_udp
from mitm_proxy.net.endpoints import DEFAULT_TAKEOVER_S, BaseEndpoint, Role, UdpEndpoint
from mitm_proxy.net.rules import rules_from_options
from mitm_proxy.net.tcp_serial import SerialEndpoint, TcpClientEndpoint, TcpServerEndpoint
from secuav_common.urls import Endpoint

STREAM_ENDPOINTS: dict[str, type[TcpClientEndpoint | TcpServerEndpoint | SerialEndpoint]] = {
    "tcp": TcpClientEndpoint,
    "tcpin": TcpServerEndpoint,
    "serial": SerialEndpoint,
}


def make_endpoint(
    ep: Endpoint, name: str, role: Role, takeover_after_s: float = DEFAULT_TAKEOVER_S, source: str = "<url>"
) -> BaseEndpoint:
    """The endpoint class for the URL's scheme, with the rules its options give; UDP on the compiled fast path
    when it is built and not turned off (``SECUAV_PROXY_PYTHON=1``, :func:`native_udp.enabled`)."""
    rules = rules_from_options(ep, source)
    if ep.mode in ("udpin", "udpout"):
        cls = native_udp.NativeUdpEndpoint if native_udp.enabled() else UdpEndpoint
        return cls(ep, name, takeover_after_s, role, rules)
    return STREAM_ENDPOINTS[ep.mode](ep, name, role, rules)

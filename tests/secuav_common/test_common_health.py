"""The container health checks against real sockets on loopback."""

from __future__ import annotations

import socket

from secuav_common.health import main


def test_udp_bound_and_tcp_peer_see_real_sockets() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp, socket.socket() as server:
        udp.bind(("127.0.0.1", 0))
        port = udp.getsockname()[1]
        assert main(["udp-bound", str(port)]) == 0
        server.bind(("127.0.0.1", 0))
        server.listen()
        tport = server.getsockname()[1]
        assert main(["tcp-peer", str(tport)]) == 1  # listening is not connected
        with socket.create_connection(("127.0.0.1", tport)):
            conn, _ = server.accept()
            with conn:
                assert main(["udp-bound", str(port), "tcp-peer", str(tport)]) == 0
    assert main(["udp-bound", str(port)]) == 1
    assert main(["nope", "1"]) == 2 and main([]) == 2

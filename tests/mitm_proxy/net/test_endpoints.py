"""UDP endpoints on 127.0.0.1: udpin follows its last sender, udpout keeps its peer, faults never close them."""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable

import pytest

from mitm_proxy.net.endpoints import UdpEndpoint
from secuav_common.urls import parse_endpoint

pytestmark = pytest.mark.timeout(20)


def client(port: int | None = None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port or 0))
    sock.settimeout(2.0)
    return sock


async def recv(sock: socket.socket) -> tuple[bytes, tuple[str, int]]:
    return await asyncio.to_thread(sock.recvfrom, 65535)


async def until(cond: Callable[[], bool], timeout_s: float = 2.0) -> None:
    for _ in range(int(timeout_s / 0.01)):
        if cond():
            return
        await asyncio.sleep(0.01)
    raise AssertionError("condition not met")


async def test_udpin_pins_its_peer_and_follows_it_only_after_silence(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "mitm_proxy.net.endpoints")
    port = udp_port()
    got: list[bytes] = []
    ep = await UdpEndpoint(parse_endpoint(f"udpin://127.0.0.1:{port}"), "vehicle", takeover_after_s=0.3).open()
    ep.receiver = lambda data, rx_s: got.append(data)
    a, b = client(), client()
    try:
        assert not ep.send(b"early") and not ep.send(b"early again")  # nobody to answer yet: counted, logged once
        assert ep.faults["no_peer"] == 2
        a.sendto(b"from a", ("127.0.0.1", port))
        await until(lambda: got == [b"from a"])
        assert ep.send(b"to a")
        assert (await recv(a))[0] == b"to a"
        for _ in range(3):  # a stranger while a is talking: dropped, counted, logged once; a keeps the replies
            b.sendto(b"stranger", ("127.0.0.1", port))
            a.sendto(b"from a", ("127.0.0.1", port))
        await until(lambda: ep.faults["stranger"] == 3 and len(got) == 4)
        assert b"stranger" not in got and ep.peer == a.getsockname()
        await asyncio.sleep(0.35)  # a falls silent (the vehicle restarted on a new source port)
        b.sendto(b"from b", ("127.0.0.1", port))
        await until(lambda: got[-1] == b"from b")
        assert ep.send(b"to b")
        data, _ = await recv(b)
        assert data == b"to b" and ep.peer == b.getsockname() and ep.faults["peer_changed"] == 1
    finally:
        ep.close()
        a.close()
        b.close()
    assert sum("endpoint.no_peer" in r.message for r in caplog.records) == 1
    assert sum("endpoint.stranger" in r.message for r in caplog.records) == 1
    assert sum("endpoint.peer_changed" in r.message for r in caplog.records) == 1


async def test_udpout_survives_a_vanished_peer(udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture) -> None:
    """ICMP port unreachable from a closed ground client is counted and mutes the peer, logged once; the socket
    stays usable and the peer is sent to again as soon as it speaks."""
    port = udp_port()
    ep = await UdpEndpoint(parse_endpoint(f"udpout://127.0.0.1:{port}"), "ground").open()
    got: list[bytes] = []
    ep.receiver = lambda data, rx_s: got.append(data)
    try:
        for _ in range(50):  # nobody listens on port: the kernel answers with ICMP port unreachable
            ep.send(b"x")
            await asyncio.sleep(0.002)
        assert ep.muted and ep.muted_dropped > 0  # the kernel's ICMP errors reach us on the standard loop
        peer = client(port)  # the ground client comes back
        try:
            assert ep.local is not None
            peer.sendto(b"reply", ep.local)
            await until(lambda: got == [b"reply"])
            assert not ep.muted
            assert ep.send(b"hello")
            assert (await recv(peer))[0] == b"hello"
            stranger = client()
            stranger.sendto(b"not ours", ep.local)  # only the fixed peer speaks for this endpoint
            await asyncio.sleep(0.05)
            stranger.close()
            assert got == [b"reply"] and ep.faults["foreign_sender"] == 1
        finally:
            peer.close()
    finally:
        ep.close()
    assert ep.tx + ep.muted_dropped == 51
    assert ep.faults["unreachable"] >= 1
    assert sum(r.getMessage() == "endpoint.muted" for r in caplog.records) == 1


def test_under_uvloop_a_vanished_peer_is_survived(udp_port: Callable[[], int]) -> None:
    """uvloop crashes on ICMP errors reported with IP_RECVERR; the endpoint must not ask for them there."""
    uvloop = pytest.importorskip("uvloop")

    async def body() -> None:
        port = udp_port()
        ep = await UdpEndpoint(parse_endpoint(f"udpout://127.0.0.1:{port}"), "ground").open()
        try:
            for _ in range(20):
                ep.send(b"x")
                await asyncio.sleep(0.002)
            peer = client(port)
            try:
                assert ep.send(b"still here")
                assert (await recv(peer))[0] == b"still here"
            finally:
                peer.close()
        finally:
            ep.close()

    uvloop.run(body())


async def test_udpin_port_taken_is_an_oserror(udp_port: Callable[[], int]) -> None:
    port = udp_port()
    first = await UdpEndpoint(parse_endpoint(f"udpin://127.0.0.1:{port}"), "a").open()
    try:
        with pytest.raises(OSError):
            await UdpEndpoint(parse_endpoint(f"udpin://127.0.0.1:{port}"), "b").open()
    finally:
        first.close()


async def test_an_oversize_datagram_is_dropped_unread_and_never_becomes_the_peer(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    from mitm_proxy.net.endpoints import MAX_DATAGRAM_BYTES

    caplog.set_level(logging.INFO, "mitm_proxy.net.endpoints")
    port = udp_port()
    got: list[bytes] = []
    ep = await UdpEndpoint(parse_endpoint(f"udpin://127.0.0.1:{port}"), "ground").open()
    ep.receiver = lambda data, rx_s: got.append(data)
    hostile, honest = client(), client()
    try:
        crafted = b"\xfd" * 65000  # 6-20 ms to split; here one length comparison
        for _ in range(5):
            hostile.sendto(crafted, ("127.0.0.1", port))
        await until(lambda: ep.faults["oversize"] == 5)
        assert got == [] and ep.peer is None  # it was not read and did not claim the endpoint
        hostile.sendto(b"x" * MAX_DATAGRAM_BYTES, ("127.0.0.1", port))  # at the limit: read as usual
        honest.sendto(b"small", ("127.0.0.1", port))
        await until(lambda: len(got) == 1)
        assert got == [b"x" * MAX_DATAGRAM_BYTES] and ep.peer == hostile.getsockname()
    finally:
        ep.close()
        hostile.close()
        honest.close()
    assert sum("endpoint.oversize" in r.message for r in caplog.records) == 1  # counted per datagram, logged once

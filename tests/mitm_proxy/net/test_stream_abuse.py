"""No TCP peer can stall the others (issue 28, findings 3 and 4): the real proxy, real sockets on loopback.

A spectator that floods garbage is evicted while another vehicle's frames keep
flowing; a ``tcpin`` endpoint serves at most ``max_clients``; a client that
never reads is evicted; a ``tcp`` vehicle that accepts and never sends is
dialled again.
"""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Callable

import pytest

from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.net import tcp_serial
from mitm_proxy.net.factory import make_endpoint
from mitm_proxy.net.tcp_serial import TcpClientEndpoint, TcpServerEndpoint
from secuav_common.loading import InputError
from secuav_common.urls import parse_endpoint
from tests.support.udp_peers import Peer, heartbeat, packer

pytestmark = pytest.mark.timeout(90)


async def until(check: Callable[[], bool], limit_s: float, what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + limit_s
    while not check():
        assert loop.time() < deadline, f"{what}: not within {limit_s} s"
        await asyncio.sleep(0.05)


def _flood(port: int, total: int, outcome: dict[str, object]) -> None:
    """Connect and send ``total`` bytes of ``fd 00`` (the review's flood) as fast as the socket takes them."""
    chunk = b"\xfd\x00" * 32768
    sent = 0
    with socket.create_connection(("127.0.0.1", port)) as sock:
        try:
            while sent < total:
                sock.sendall(chunk)
                sent += len(chunk)
            sock.settimeout(10)
            outcome["eof"] = sock.recv(65536) == b""  # the proxy hung up on us
        except OSError as exc:  # reset while we were still sending: hung up too
            outcome["error"] = type(exc).__name__
    outcome["sent"] = sent


async def test_a_garbage_flood_on_one_endpoint_evicts_that_client_and_the_other_vehicle_flows(
    udp_port: Callable[[], int], tcp_port: Callable[[], int], monkeypatch: pytest.MonkeyPatch
) -> None:
    # A smaller budget than the real 64 kB/s, so that even a proxy slowed by a busy machine (which reads a
    # stream only as fast as it frames it) sees the flood go over it within the test.
    monkeypatch.setattr(tcp_serial, "GARBAGE_BYTES_PER_S", 16 * 1024)
    v1, v2, gtcp = udp_port(), udp_port(), tcp_port()
    ground2 = Peer()
    config = ProxyConfig(links=[
        LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{v1}", ground=[f"tcpin://127.0.0.1:{gtcp}?listen_only=true"]),
        LinkConfig(sysid=2, vehicle=f"udpin://127.0.0.1:{v2}", ground=[f"udpout://127.0.0.1:{ground2.port}"]),
    ], broker="none")  # fmt: skip
    vehicle2 = Peer()
    mav = packer(2)
    frames = [heartbeat(mav) for _ in range(500)]
    outcome: dict[str, object] = {}
    try:
        async with Proxy(config) as proxy:
            collect = asyncio.create_task(ground2.frames(quiet_s=3.0))  # read as they come: no socket overflow
            flood = asyncio.create_task(asyncio.to_thread(_flood, gtcp, 4 * 1024 * 1024, outcome))
            for frame in frames:  # 500 frames at ~200 Hz while the flood goes on
                vehicle2.send(frame, v2)
                await asyncio.sleep(0.005)
            await flood
            got, _ = await collect
            tcp_ep = next(ep for ep in proxy.endpoints.values() if isinstance(ep, TcpServerEndpoint))
            assert tcp_ep.faults["client_evicted"] >= 1, tcp_ep.faults
            assert tcp_ep.clients == []
    finally:
        vehicle2.close()
        ground2.close()
    assert outcome.get("eof") or outcome.get("error"), outcome
    assert got == frames  # every frame of the other vehicle, in order


async def test_a_tcpin_endpoint_serves_at_most_max_clients(tcp_port: Callable[[], int]) -> None:
    port = tcp_port()
    ep = make_endpoint(parse_endpoint(f"tcpin://127.0.0.1:{port}?max_clients=2"), "ground:test", "ground")
    assert isinstance(ep, TcpServerEndpoint) and ep.max_clients == 2
    await ep.open()
    socks: list[socket.socket] = []
    try:
        for _ in range(3):
            sock = socket.create_connection(("127.0.0.1", port))
            sock.settimeout(5)
            socks.append(sock)
        await until(lambda: ep.faults["client_refused"] == 1, 5, "the third client refused")
        assert len(ep.clients) == 2
        frame = heartbeat(packer(1))
        assert ep.send(frame)
        assert [await asyncio.to_thread(s.recv, 4096) for s in socks[:2]] == [frame, frame]
        assert await asyncio.to_thread(socks[2].recv, 4096) == b""  # closed on it
        assert ep.snapshot()["max_clients"] == 2
    finally:
        for sock in socks:
            sock.close()
        ep.close()


@pytest.mark.parametrize(("url", "words"), [
    ("tcpin://127.0.0.1:5760?max_clients=0", "max_clients"),
    ("tcpin://127.0.0.1:5760?max_clients=lots", "lots"),
    ("udpin://127.0.0.1:14550?max_clients=3", "unknown option"),
])  # fmt: skip
def test_max_clients_is_checked_and_only_for_tcpin(url: str, words: str) -> None:
    with pytest.raises(InputError, match=words):
        make_endpoint(parse_endpoint(url), "ground:test", "ground")


async def test_a_client_that_never_reads_is_evicted_and_the_others_keep_receiving(
    tcp_port: Callable[[], int], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tcp_serial, "SLOW_CLIENT_S", 0.5)
    port = tcp_port()
    ep = make_endpoint(parse_endpoint(f"tcpin://127.0.0.1:{port}"), "ground:test", "ground")
    await ep.open()
    stuck = socket.socket()
    stuck.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stuck.connect(("127.0.0.1", port))
    reader = socket.create_connection(("127.0.0.1", port))
    received = bytearray()
    stop = threading.Event()

    def read() -> None:
        reader.settimeout(0.2)
        while not stop.is_set():
            try:
                data = reader.recv(65536)
            except TimeoutError:
                continue
            if not data:
                return
            received.extend(data)

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    assert isinstance(ep, TcpServerEndpoint)
    try:
        await until(lambda: len(ep.clients) == 2, 5, "both clients connected")
        frame = heartbeat(packer(1)) * 50  # ~1 kB a send
        loop = asyncio.get_running_loop()
        end = loop.time() + 8
        while ep.faults["slow_peer_evicted"] == 0 and loop.time() < end:
            ep.send(frame)
            await asyncio.sleep(0.001)
        assert ep.faults["slow_peer_evicted"] == 1, ep.faults
        await until(lambda: len(ep.clients) == 1, 5, "the stuck client gone")
        before = len(received)
        for _ in range(20):
            ep.send(frame)
            await asyncio.sleep(0.01)
        await until(lambda: len(received) >= before + 20 * len(frame), 5, "the reading client still served")
    finally:
        stop.set()
        thread.join(5)
        stuck.close()
        reader.close()
        ep.close()


async def test_a_tcp_vehicle_that_accepts_and_never_sends_is_dialled_again(
    tcp_port: Callable[[], int], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(TcpClientEndpoint, "silent_after_s", 0.6)
    port = tcp_port()
    accepted: list[asyncio.StreamWriter] = []

    async def mute(_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        accepted.append(writer)  # accept, never send, never close

    server = await asyncio.start_server(mute, "127.0.0.1", port)
    ep = make_endpoint(parse_endpoint(f"tcp://127.0.0.1:{port}"), "vehicle:test", "vehicle")
    assert isinstance(ep, TcpClientEndpoint)
    await ep.open()
    try:
        await until(lambda: len(accepted) >= 2, 10, "a second dial after the silence")
        assert ep.faults["silent_peer"] >= 1 and ep.connects >= 2
    finally:
        ep.close()
        for writer in accepted:
            writer.close()
        server.close()
        await server.wait_closed()

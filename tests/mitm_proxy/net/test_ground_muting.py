"""A ground endpoint nobody listens on is muted, and resumes when someone does (issue 37, item 4).

The default configuration names two ground ports; often only one has a client. Real proxy in-process, real
loopback sockets: a port that was bound and closed (the kernel answers it with ICMP port unreachable), then
a listener appearing on that same port. Each test runs on the fast path and on the pure-Python one.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import pytest

from mitm_proxy.app import Proxy, stats_line
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.net.endpoints import PROBE_INTERVAL_S, UdpEndpoint
from mitm_proxy.tools.attack_cli import _stats_line
from tests.conftest import require_fast_path
from tests.support.udp_peers import Peer, heartbeat, packer

pytestmark = [pytest.mark.timeout(40), pytest.mark.usefixtures("proxy_path")]


def closed_port() -> int:
    """A loopback port that was just bound and closed: nobody listens there."""
    p = Peer()
    port = p.port
    p.close()
    return port


def ground_of(proxy: Proxy, port: int) -> UdpEndpoint:
    ep = next(ep for url, ep in proxy.endpoints.items() if url.port == port)
    assert isinstance(ep, UdpEndpoint)
    return ep


async def feed(vehicle: Peer, veh: int, frames: list[bytes], gap_s: float = 0.001) -> None:
    for frame in frames:
        vehicle.send(frame, veh)
        await asyncio.sleep(gap_s)


async def test_a_closed_ground_port_is_muted_then_resumed_by_a_probe(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture, proxy_path: str
) -> None:
    caplog.set_level(logging.INFO, logger="mitm_proxy.net.endpoints")
    stays, gone = Peer(), closed_port()
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                      ground=[f"udpout://127.0.0.1:{stays.port}", f"udpout://127.0.0.1:{gone}"])  # fmt: skip
    vehicle, back = Peer(), None
    mav = packer(1)
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none")) as proxy:
            muted = ground_of(proxy, gone)
            sent = [heartbeat(mav) for _ in range(150)]  # within a test socket's receive buffer, read at the end
            await feed(vehicle, veh, sent, gap_s=0.002)
            # The listening ground loses nothing; the closed one stopped being sent to.
            assert (await stays.frames())[0] == sent
            assert muted.muted and muted.mutes == 1
            assert muted.muted_dropped > 100 and muted.tx < 40  # a few before the first ICMP, then a probe at 4 Hz
            stats = proxy.stats_snapshot()[1]
            snap = stats["endpoints"][muted.name]
            assert snap["muted"] is True and snap["muted_dropped"] == muted.muted_dropped
            assert stats_line(1, stats)["muted"] == muted.name  # the periodic log line names it
            assert f"{muted.name} muted ({muted.muted_dropped} datagrams not sent)" in _stats_line(stats)  # status

            back = Peer(gone)  # the ground client comes up on that port; it sends nothing
            probe, tries = [], 0
            while not probe:  # a probe reaches it within PROBE_INTERVAL_S, then the endpoint resumes
                await feed(vehicle, veh, [heartbeat(mav)], gap_s=0.005)
                probe, _ = await back.frames(0.0 if tries % 10 else 0.01)
                tries += 1
                assert tries * 0.005 < 20 * PROBE_INTERVAL_S
            later = [heartbeat(mav) for _ in range(50)]
            await asyncio.sleep(0.15)  # past the probe's confirmation window, with no ICMP error
            await feed(vehicle, veh, later)
            got, _ = await back.frames()
            assert got[-len(later) :] == later  # from the resumption on, nothing lost to the new listener
            assert not muted.muted
            assert (await stays.frames())[0][-len(later) :] == later
    finally:
        vehicle.close()
        stays.close()
        if back is not None:
            back.close()
    messages = [r.getMessage() for r in caplog.records]
    assert messages.count("endpoint.muted") == 1 and messages.count("endpoint.resumed") == 1


async def test_a_muted_ground_resumes_at_once_when_its_client_sends(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="mitm_proxy.net.endpoints")
    stays, gone = Peer(), closed_port()
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                      ground=[f"udpout://127.0.0.1:{stays.port}", f"udpout://127.0.0.1:{gone}"])  # fmt: skip
    vehicle, back = Peer(), None
    mav, gcs_mav = packer(1), packer(255, 190)
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none")) as proxy:
            muted = ground_of(proxy, gone)
            await feed(vehicle, veh, [heartbeat(mav) for _ in range(100)])
            await stays.frames()
            assert muted.muted and muted.local is not None
            back = Peer(gone)
            back.reply(heartbeat(gcs_mav), muted.local)  # a GCS's heartbeat: it listens, resume now
            uplink, _ = await vehicle.frames()
            assert len(uplink) == 1 and not muted.muted
            later = [heartbeat(mav) for _ in range(50)]
            await feed(vehicle, veh, later)
            assert (await back.frames())[0] == later  # every frame after its first datagram
            assert (await stays.frames())[0] == later
    finally:
        vehicle.close()
        stays.close()
        if back is not None:
            back.close()
    resumed = [r for r in caplog.records if r.getMessage() == "endpoint.resumed"]
    assert len(resumed) == 1 and getattr(resumed[0], "detail", "") == "the peer sent a datagram"


def test_on_uvloop_the_fast_path_mutes_a_closed_port(udp_port: Callable[[], int]) -> None:
    """The default loop is uvloop, whose own transport must not be asked for ICMP errors; the fast path's
    endpoints read their socket themselves, so the default configuration is muted there too."""
    uvloop = pytest.importorskip("uvloop")
    from mitm_proxy.net import native_udp
    from secuav_common.urls import parse_endpoint

    require_fast_path()

    async def body() -> None:
        port = closed_port()
        ep = await native_udp.NativeUdpEndpoint(parse_endpoint(f"udpout://127.0.0.1:{port}"), "ground").open()
        try:
            for _ in range(40):
                ep.send(b"x")
                await asyncio.sleep(0.002)
            assert ep.muted and ep.muted_dropped > 20
            back = Peer(port)
            try:
                assert ep.local is not None
                back.reply(b"here", ep.local)
                for _ in range(200):
                    if not ep.muted:
                        break
                    await asyncio.sleep(0.005)
                assert not ep.muted and ep.send(b"hello")
                await asyncio.sleep(0.05)  # (uvloop has no sock_recvfrom)
                assert back.sock.recvfrom(100)[0] == b"hello"
            finally:
                back.close()
        finally:
            ep.close()

    uvloop.run(body())

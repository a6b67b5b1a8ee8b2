"""Bad input and faults: forwarding never stops and no valid frame of the other direction is lost.

Real proxy in-process, real sockets on 127.0.0.1, real MAVLink frames (pymavlink),
a real broker (amqtt) that goes away and comes back.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import AsyncIterator, Callable

import pytest

from mavframe.frames import split
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.broker import EmbeddedBroker
from tests.support.udp_peers import Peer, command, heartbeat, packer

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.timeout(40), pytest.mark.usefixtures("proxy_path")]


@contextlib.asynccontextmanager
async def one_link(udp_port: Callable[[], int], grounds: int = 1, **extra: object
                   ) -> AsyncIterator[tuple[Proxy, int, list[Peer]]]:  # fmt: skip
    gcs = [Peer() for _ in range(grounds)]
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{g.port}" for g in gcs])
    try:
        async with Proxy(ProxyConfig(links=[link], **{"broker": "none", **extra})) as proxy:  # type: ignore[arg-type]
            yield proxy, veh, gcs
    finally:
        for g in gcs:
            g.close()


async def test_malformed_datagrams_lose_no_valid_frame(udp_port: Callable[[], int]) -> None:
    async with one_link(udp_port) as (proxy, veh, (gcs,)):
        vehicle = Peer()
        try:
            mav = packer(1)
            good = [heartbeat(mav) for _ in range(6)]
            bad_crc = bytearray(heartbeat(mav))
            bad_crc[-1] ^= 0xFF
            datagrams = [
                good[0],
                b"\x00garbage\xff\x13" * 5,
                b"junk" + good[1] + b"\xfd\x09" + good[2],  # garbage before, and a torn header between frames
                good[3][:-4],  # truncated
                bytes(bad_crc) + good[4],
                b"",
                good[5],
            ]
            for d in datagrams:
                vehicle.send(d, veh)
            got, proxy_addr = await gcs.frames()
            assert got == [good[0], good[1], good[2], good[4], good[5]]
            assert proxy_addr is not None
            cmds = [command(packer(255, 190), 1) for _ in range(3)]
            gcs.reply(b"\xfe\xfe\xfe" + cmds[0], proxy_addr)
            gcs.reply(cmds[1] + cmds[2], proxy_addr)
            up, _ = await vehicle.frames()
            assert up == cmds
            snap = proxy.stats_snapshot()[1]
            assert snap["downlink"]["bad_total"] >= 4 and snap["uplink"]["bad_total"] >= 1
            assert snap["downlink"]["frames_out"] == 5 and snap["uplink"]["frames_out"] == 3
        finally:
            vehicle.close()


class Flood:
    """A thread that sends ``junk`` from ``peer`` to ``addr`` as fast as it can while the block runs; ``sent``
    counts the datagrams (the kernel drops what the proxy cannot take in)."""

    def __init__(self, peer: Peer, addr: tuple[str, int], junk: bytes) -> None:
        self.peer, self.addr, self.junk = peer, addr, junk
        self.sent = 0
        self._stop = threading.Event()
        self._task: asyncio.Task[None] | None = None

    def _run(self) -> None:
        while not self._stop.is_set():
            for _ in range(200):
                with contextlib.suppress(BlockingIOError):
                    self.peer.reply(self.junk, self.addr)
                    self.sent += 1

    async def __aenter__(self) -> Flood:
        self._task = asyncio.create_task(asyncio.to_thread(self._run))
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._stop.set()
        assert self._task is not None
        await self._task


async def flooding(flood: Flood, frames_in: Callable[[], int], bound_s: float = 20.0) -> None:
    """Return once the flood is a flood (over 2,000 datagrams sent) and the proxy is taking it in (over 1,000
    frames read): counted, not timed, so that the frames under test go out in the middle of it on a loaded
    machine too. ``bound_s`` only bounds a failure."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + bound_s
    while not (flood.sent > 2000 and frames_in() > 1000):
        assert loop.time() < deadline, f"no flood: {flood.sent} datagrams sent, {frames_in()} frames read"
        await asyncio.sleep(0.01)


# The frames under test are collected by count (Peer.take), not until a silence: a loaded machine can pause the
# proxy (and this process) for longer than any silence a test would wait, and the last frames then came after
# the collector had given up (the telemetry-flood test failed so at 0.5 s, the ground-flood one at 0.5 s before
# it waited 2 s). A frame the proxy really lost still fails the test: take() returns short after its bound.


async def test_a_flood_from_the_ground_does_not_starve_the_vehicle(udp_port: Callable[[], int]) -> None:
    """A ground client floods the proxy (valid frames and garbage); every vehicle frame still reaches the GCS."""
    async with one_link(udp_port, grounds=2) as (proxy, veh, (gcs, flooder_ep)):
        vehicle = Peer()
        try:
            vehicle.send(heartbeat(packer(1)), veh)  # the proxy learns the vehicle and tells the ground side
            await gcs.take(1)
            _, flood_port_addr = await flooder_ep.take(1)
            assert flood_port_addr is not None
            junk = command(packer(255, 190), 1) + b"\x00" * 40

            def uplink() -> int:
                return int(proxy.stats_snapshot()[1]["uplink"]["frames_in"])

            async with Flood(flooder_ep, flood_port_addr, junk) as flood:
                drain = asyncio.create_task(vehicle.frames(1.0))  # the vehicle side reads its uplink
                await flooding(flood, uplink)  # the flood was really processed, not just dropped by the kernel
                before = uplink()
                mav = packer(1)
                sent = []
                collect = asyncio.create_task(gcs.take(300))
                for _ in range(300):
                    frame = heartbeat(mav)
                    sent.append(frame)
                    vehicle.send(frame, veh)
                    await asyncio.sleep(0.002)
                got, _ = await collect
                flooded_meanwhile = uplink() - before
            await drain
            assert got == sent
            assert flooded_meanwhile > 0  # the proxy read the flood while it forwarded the vehicle's frames
        finally:
            vehicle.close()


async def test_a_telemetry_flood_does_not_starve_commands(udp_port: Callable[[], int]) -> None:
    """The vehicle floods the downlink; every command the GCS sends meanwhile reaches the vehicle, in order."""
    async with one_link(udp_port) as (proxy, veh, (gcs,)):
        vehicle = Peer()
        try:
            vehicle.send(heartbeat(packer(1)), veh)
            _, proxy_addr = await gcs.take(1)
            assert proxy_addr is not None

            def downlink() -> int:
                return int(proxy.stats_snapshot()[1]["downlink"]["frames_in"])

            async with Flood(vehicle, ("127.0.0.1", veh), heartbeat(packer(1))) as flood:
                sink = asyncio.create_task(gcs.frames(1.0))  # the GCS reads its telemetry
                await flooding(flood, downlink)
                before = downlink()
                g = packer(255, 190)
                sent = []
                commands = asyncio.create_task(vehicle.take(100))
                for _ in range(100):
                    cmd = command(g, 1)
                    sent.append(cmd)
                    gcs.reply(cmd, proxy_addr)
                    await asyncio.sleep(0.005)
                got, _ = await commands
                flooded_meanwhile = downlink() - before
            await sink
            assert got == sent
            assert flooded_meanwhile > 0  # the proxy read the flood while it forwarded the commands
        finally:
            vehicle.close()


async def test_vehicle_comes_back_from_a_new_port(udp_port: Callable[[], int],
                                                  caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    caplog.set_level(logging.INFO)
    async with one_link(udp_port) as (proxy, veh, (gcs,)):
        first, second = Peer(), Peer()
        try:
            first.send(heartbeat(packer(1)), veh)
            _, proxy_addr = await gcs.frames(0.2)
            assert proxy_addr is not None
            cmd = command(packer(255, 190), 1)
            gcs.reply(cmd, proxy_addr)
            assert (await first.frames(0.2))[0] == [cmd]
            first.close()  # the autopilot restarts: new socket, new source port
            # Until the old port has been silent for a second the new one is a stranger; then it is followed.
            deadline = asyncio.get_running_loop().time() + 10.0
            arrived: list[bytes] = []
            while not arrived and asyncio.get_running_loop().time() < deadline:
                second.send(heartbeat(packer(1)), veh)
                arrived = (await gcs.frames(0.1))[0]
            assert arrived
            gcs.reply(cmd, proxy_addr)
            assert (await second.frames(0.2))[0] == [cmd]
            faults = proxy.stats_snapshot()[1]["endpoints"][f"vehicle:{veh}"]["faults"]
            assert faults["peer_changed"] == 1 and set(faults) <= {"peer_changed", "stranger"}
        finally:
            second.close()
    assert sum(r.getMessage() == "endpoint.peer_changed" for r in caplog.records) == 1


async def test_a_vanished_ground_client_does_not_stop_the_others(udp_port: Callable[[], int]) -> None:
    async with one_link(udp_port, grounds=2) as (proxy, veh, (gone, stays)):
        vehicle = Peer()
        try:
            gone_port = gone.port
            gone.close()  # its port now answers with ICMP port unreachable
            mav = packer(1)
            sent = [heartbeat(mav) for _ in range(100)]
            for frame in sent:
                vehicle.send(frame, veh)
                await asyncio.sleep(0.001)
            assert (await stays.frames())[0] == sent
            back = Peer(gone_port)  # the client restarts on its port and says so (a GCS's heartbeat):
            try:  # the proxy had muted that port (nobody listened) and sends to it again from now on
                muted = next(ep for url, ep in proxy.endpoints.items() if url.port == gone_port)
                assert muted.local is not None
                back.reply(heartbeat(packer(255, 190)), muted.local)
                assert len((await vehicle.frames(0.2))[0]) == 1
                later = [heartbeat(mav) for _ in range(5)]
                for frame in later:
                    vehicle.send(frame, veh)
                assert (await back.frames())[0] == later
                assert (await stays.frames())[0] == later
                assert proxy.stats_snapshot()[1]["downlink"]["frames_out"] == 105
            finally:
                back.close()
        finally:
            vehicle.close()


async def test_broker_restart_keeps_forwarding_and_reconnects(udp_port: Callable[[], int],
                                                              tcp_port: Callable[[], int]) -> None:  # fmt: skip
    mqtt = tcp_port()
    broker = EmbeddedBroker(port=mqtt)
    await broker.__aenter__()
    async with one_link(udp_port, broker=f"mqtt://127.0.0.1:{mqtt}") as (proxy, veh, (gcs,)):
        vehicle = Peer()
        try:
            await proxy.control.wait_connected(10)
            mav = packer(1)
            sent: list[bytes] = []
            received: list[bytes] = []

            async def stream() -> None:
                while True:
                    frame = heartbeat(mav)
                    sent.append(frame)
                    vehicle.send(frame, veh)
                    await asyncio.sleep(0.01)

            async def collect() -> None:
                loop = asyncio.get_running_loop()
                while True:
                    data, _ = await loop.sock_recvfrom(gcs.sock, 65535)
                    received.extend(f for _h, f in split(data).frames)

            tasks = [asyncio.create_task(stream()), asyncio.create_task(collect())]
            await asyncio.sleep(0.5)
            await broker.__aexit__(None, None, None)  # the broker goes away
            gone_at = len(sent)
            # 100 frames sent after it went (1 s at 100 Hz on an idle machine) come through; counted, not timed,
            # so a loaded machine that sends fewer in a second does not fail it.
            for _ in range(400):
                if len(received) > gone_at + 100:
                    break
                await asyncio.sleep(0.05)
            assert len(received) > gone_at + 100
            broker = EmbeddedBroker(port=mqtt)
            await broker.__aenter__()  # and comes back
            for _ in range(200):
                if proxy.control.connections >= 2:
                    break
                await asyncio.sleep(0.05)
            assert proxy.control.connections >= 2
            tasks[0].cancel()
            await asyncio.sleep(0.2)
            tasks[1].cancel()
            assert received == sent
        finally:
            vehicle.close()
    await broker.__aexit__(None, None, None)


async def test_a_stranger_cannot_take_the_ground_side_over(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    """udpin ground port: one spoofed datagram neither reaches the vehicle nor diverts the GCS's telemetry."""
    caplog.set_level(logging.INFO)
    veh, ground = udp_port(), udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpin://127.0.0.1:{ground}"])
    vehicle, gcs, stranger = Peer(), Peer(), Peer()
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none")) as proxy:
            vehicle.send(heartbeat(packer(1)), veh)
            await vehicle.frames(0.1)
            gcs.send(heartbeat(packer(255, 190)), ground)  # the GCS speaks first: it is the ground peer
            assert (await vehicle.frames(0.2))[0]
            stranger.send(command(packer(250, 1), 1), ground)  # e.g. an arm command from someone else
            assert (await vehicle.frames(0.3))[0] == []  # never reached the vehicle
            vehicle.send(heartbeat(packer(1)), veh)
            assert len((await gcs.frames(0.2))[0]) == 1  # telemetry still goes to the GCS...
            assert (await stranger.frames(0.2))[0] == []  # ...and not to the stranger
            faults = proxy.stats_snapshot()[1]["endpoints"][f"ground:{ground}"]["faults"]
            assert faults.get("stranger") == 1 and "peer_changed" not in faults
    finally:
        for p in (vehicle, gcs, stranger):
            p.close()
    assert sum(r.getMessage() == "endpoint.stranger" for r in caplog.records) == 1

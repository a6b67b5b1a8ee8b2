"""Router-grade endpoints through the real proxy: TCP both ways, a serial radio, per-endpoint rules.

Peers are real: MAVProxy as a spectator GCS on ``tcpin``, pymavlink's own TCP
connections (``mavutil``) as vehicle and GCS, a pseudo-terminal pair standing
in for a telemetry radio's serial port, the flight simulator as the vehicle.
"""

from __future__ import annotations

import asyncio
import os
import sys
import time
import tty
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink import mavutil

from mavframe.frames import split
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from tests.support.live_sim import live_sim, until
from tests.support.udp_peers import Peer, distance, heartbeat, packer

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.timeout(60), pytest.mark.usefixtures("proxy_path")]


def _proxy(vehicle: str, *ground: str) -> Proxy:
    return Proxy(ProxyConfig(links=[LinkConfig(sysid=1, vehicle=vehicle, ground=list(ground))], broker="none"))


@pytest.mark.parametrize("listen_only", [True, False])
async def test_a_listen_only_mavproxy_sees_the_vehicle_and_cannot_arm_it(
    listen_only: bool, udp_port: Callable[[], int], tcp_port: Callable[[], int], tmp_path: Path
) -> None:
    pytest.importorskip("MAVProxy", reason="MAVProxy comes with the project's test extras")
    mavproxy = Path(sys.executable).parent / "mavproxy.py"
    vport, gport = udp_port(), tcp_port()
    flag = "true" if listen_only else "false"
    async with _proxy(f"udpin://127.0.0.1:{vport}", f"tcpin://127.0.0.1:{gport}?listen_only={flag}") as proxy, \
            live_sim("wall_hover", [vport]) as runner:  # fmt: skip
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(mavproxy), f"--master=tcp:127.0.0.1:{gport}", "--non-interactive",
            f"--state-basedir={tmp_path}", "--cmd=module unload terrain; arm throttle",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT, cwd=tmp_path,
        )  # fmt: skip
        assert proc.stdout is not None
        seen: list[str] = []

        async def read() -> None:
            assert proc.stdout is not None
            while raw := await proc.stdout.readline():
                seen.append(raw.decode(errors="replace").strip())

        reader = asyncio.create_task(read())
        vehicle = runner.sim.vehicles[1]
        endpoint = proxy.links[0].grounds[0]
        try:
            await until(lambda: any("Detected vehicle 1:1" in s for s in seen), 20, "MAVProxy to see the vehicle")
            if listen_only:
                await until(lambda: endpoint.gate.listen_only_sent["COMMAND_LONG"] >= 1, 10, "the arm command")
                await asyncio.sleep(1.0)
                assert not vehicle.armed
                snap = proxy.stats_snapshot()[1]
                assert snap["endpoints"][endpoint.name]["listen_only_dropped"]["COMMAND_LONG"] >= 1
                assert snap["uplink"]["frames_in"] == 0  # nothing of MAVProxy's reached the link
            else:
                await until(lambda: vehicle.armed, 10, "the vehicle to arm (the control run)")
        finally:
            if proc.returncode is None:
                proc.terminate()
            await asyncio.wait_for(proc.wait(), 10)
            reader.cancel()
    assert any("Mode" in s for s in seen), seen[-20:]


async def test_pymavlink_over_tcp_as_vehicle_server_and_gcs_client(tcp_port: Callable[[], int]) -> None:
    """Vehicle: a TCP server as ArduPilot SITL is (the proxy dials it); GCS: a TCP client of the proxy's server."""
    vport, gport = tcp_port(), tcp_port()
    vehicle = await asyncio.to_thread(mavutil.mavlink_connection, f"tcpin:127.0.0.1:{vport}", source_system=1)
    gcs = None
    try:
        async with _proxy(f"tcp://127.0.0.1:{vport}", f"tcpin://127.0.0.1:{gport}") as proxy:
            gcs = await asyncio.to_thread(mavutil.mavlink_connection, f"tcp:127.0.0.1:{gport}", source_system=255)
            mav = packer(1)
            sent = [heartbeat(mav), distance(mav, 250, 1), distance(mav, 251, 2)] * 20

            async def stream() -> None:
                await until(lambda: proxy.links[0].vehicle.connection is not None, 10, "the proxy to dial the vehicle")
                await until(lambda: vehicle.recv() is not None and vehicle.port is not None, 5, "the vehicle to accept")
                for frame in sent:  # one write per frame, so TCP cuts them wherever it likes
                    vehicle.write(frame)
                    await asyncio.sleep(0.002)

            def receive(n: int, timeout_s: float = 20) -> list[bytes]:
                got: list[bytes] = []
                deadline = time.monotonic() + timeout_s
                while len(got) < n and time.monotonic() < deadline:
                    msg = gcs.recv_match(blocking=True, timeout=0.2) if gcs is not None else None
                    if msg is not None:
                        got.append(bytes(msg.get_msgbuf()))
                return got

            writer = asyncio.create_task(stream())
            got = await asyncio.to_thread(receive, len(sent))
            await writer
            assert got == sent  # byte for byte, in order, none lost
            command = packer(255, 190).command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            gcs.mav.srcSystem, gcs.mav.srcComponent = 255, 190
            gcs.mav.send(command)
            msg = await asyncio.to_thread(vehicle.recv_match, type="COMMAND_LONG", blocking=True, timeout=10)
            assert msg is not None and msg.command == 400
            assert proxy.stats_snapshot()[1]["endpoints"][proxy.links[0].grounds[0].name]["clients"] == 1
    finally:
        vehicle.close()
        if gcs is not None:
            gcs.close()


async def test_a_tcp_vehicle_link_waits_for_the_server_and_reconnects(tcp_port: Callable[[], int]) -> None:
    vport = tcp_port()
    gcs = Peer()
    received: list[bytes] = []

    async def serve_once(server_started: asyncio.Event, hang_up: asyncio.Event) -> None:
        async def on_client(_r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            w.write(heartbeat(packer(1)))
            await w.drain()
            await hang_up.wait()
            w.close()

        server = await asyncio.start_server(on_client, "127.0.0.1", vport)
        server_started.set()
        async with server:
            await hang_up.wait()
            await asyncio.sleep(0.1)

    try:
        async with _proxy(f"tcp://127.0.0.1:{vport}", f"udpout://127.0.0.1:{gcs.port}") as proxy:
            ep = proxy.links[0].vehicle
            await asyncio.sleep(0.6)  # the server is not up: the proxy keeps trying, it does not fail
            assert ep.faults["connect_failed"] >= 1 and ep.connection is None
            for round_ in range(2):
                started, hang_up = asyncio.Event(), asyncio.Event()
                task = asyncio.create_task(serve_once(started, hang_up))
                await started.wait()
                await until(lambda n=round_: ep.connects > n, 10, f"connection {round_ + 1}")
                frames, _ = await gcs.frames(quiet_s=0.5)
                received.extend(frames)
                hang_up.set()
                await task
                await until(lambda: ep.connection is None, 5, "the hang-up to be noticed")
            assert len(received) == 2 and ep.faults["disconnected"] >= 2
    finally:
        gcs.close()


async def test_a_serial_radio_over_a_pty_pair(udp_port: Callable[[], int]) -> None:
    """The vehicle end is a pseudo-terminal as a USB radio would be; frames cut anywhere arrive whole."""
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    gcs = Peer()
    loop = asyncio.get_running_loop()
    try:
        async with _proxy(f"serial://{path}?baud=115200", f"udpout://127.0.0.1:{gcs.port}") as proxy:
            await until(lambda: proxy.links[0].vehicle.connection is not None, 10, "the serial port to open")
            mav = packer(1)
            stream = b"".join([heartbeat(mav), distance(mav, 250, 1)] * 10)
            for i in range(0, len(stream), 17):  # the radio hands bytes over in odd-sized pieces
                os.write(master, stream[i : i + 17])
                await asyncio.sleep(0.001)
            got, proxy_addr = await gcs.frames(quiet_s=0.5)
            assert b"".join(got) == stream
            assert proxy_addr is not None
            command = packer(255, 190).command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(packer(255, 190))
            gcs.reply(command, proxy_addr)
            back = b""
            while len(back) < len(command):
                back += await asyncio.wait_for(loop.run_in_executor(None, os.read, master, 1024), 5)
            assert [f for _h, f in split(back).frames] == [command]
            vehicle_side = proxy.stats_snapshot()[1]["endpoints"][proxy.links[0].vehicle.name]
            assert vehicle_side["peer"] == path and vehicle_side["url"] == f"serial://{path}?baud=115200"
    finally:
        gcs.close()
        os.close(master)
        os.close(slave)


async def test_a_deny_rule_on_one_ground_endpoint_leaves_the_others_alone(udp_port: Callable[[], int]) -> None:
    vport = udp_port()
    plain, filtered, vehicle = Peer(), Peer(), Peer()
    try:
        async with _proxy(f"udpin://127.0.0.1:{vport}", f"udpout://127.0.0.1:{plain.port}",
                          f"udpout://127.0.0.1:{filtered.port}?deny=DISTANCE_SENSOR") as proxy:  # fmt: skip
            mav = packer(1)
            for _ in range(25):
                vehicle.send(heartbeat(mav) + distance(mav, 250, 1), vport)  # both in one datagram
                vehicle.send(distance(mav, 251, 2), vport)  # alone: nothing left to send
            got_plain, _ = await plain.frames()
            got_filtered, _ = await filtered.frames()
            ids = lambda frames: [split(f).frames[0][0].msgid for f in frames]  # noqa: E731
            assert ids(got_plain).count(132) == 50 and ids(got_plain).count(0) == 25
            assert ids(got_filtered) == [0] * 25
            ep = proxy.links[0].grounds[1]
            assert proxy.stats_snapshot()[1]["endpoints"][ep.name]["dropped"] == {"down.deny": 50}
    finally:
        for peer in (plain, filtered, vehicle):
            peer.close()

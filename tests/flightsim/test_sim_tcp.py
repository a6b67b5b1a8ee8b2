"""``secuav-sim --mavlink tcpin://...``: the simulator serves MAVLink on TCP as SITL does on 5760.

A pymavlink ground station connects straight to it (``tcp:HOST:PORT``, as
MAVProxy's ``--master=tcp:`` does), gets the vehicle's stream and an answer to
its command; then ``secuav-proxy --vehicle tcp://...`` dials the simulator and
a ground station behind the proxy sees the same vehicle.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from pymavlink import mavutil

from secuav_common.broker import port_in_use
from tests.conftest import free_tcp_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


@contextmanager
def running(args: list[str], log: Path) -> Iterator[subprocess.Popen[bytes]]:
    proc = subprocess.Popen([sys.executable, "-m", *args], stdout=log.open("wb"), stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    try:
        yield proc
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _wait_port(port: int, proc: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + 30
    while not port_in_use("127.0.0.1", port):
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, "the simulator's TCP port never opened"
        time.sleep(0.1)


def test_a_ground_station_connects_over_tcp_directly_and_through_the_proxy(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()
    with running(["flightsim", "wall_hover", "--mavlink", f"tcpin://127.0.0.1:{port}"], tmp_path / "sim.log") as sim:
        _wait_port(port, sim, tmp_path / "sim.log")
        gcs = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
        try:
            hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
            assert hb is not None and hb.get_srcSystem() == 1
            gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=10)
            assert ack is not None and ack.command == mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE
            assert ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
            assert gcs.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=10) is not None
        finally:
            gcs.close()

        ground = udp_port()
        proxy_args = ["mitm_proxy", "--broker", "none", "--vehicle", f"tcp://127.0.0.1:{port}",
                      "--ground", f"udpin://127.0.0.1:{ground}"]  # fmt: skip
        with running(proxy_args, tmp_path / "proxy.log"):
            behind = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ground}", source_system=255)
            try:
                deadline = time.monotonic() + 20
                got = None
                while got is None and time.monotonic() < deadline:
                    behind.mav.heartbeat_send(6, 8, 0, 0, 0)  # a udpin endpoint answers whoever spoke first
                    got = behind.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.5)
                assert got is not None, (tmp_path / "proxy.log").read_text()
                assert got.get_srcSystem() == 1
            finally:
                behind.close()
    assert "tcp.client" in (tmp_path / "sim.log").read_text()


async def test_udp_host_names_are_looked_up_once_when_the_link_opens(udp_port: Callable[[], int]) -> None:
    """``udpout://localhost:PORT`` (or a compose service name) works: sent to the address, replies matched to it."""
    import asyncio
    import socket

    from flightsim.mavlink.udp import UdpLink
    from secuav_common.urls import parse_endpoint

    port = udp_port()
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", port))
    listener.settimeout(5)
    got: list[bytes] = []
    link = await UdpLink(parse_endpoint(f"udpout://localhost:{port}"), lambda data, now: got.append(data)).open()
    try:
        link.send(b"hello")
        link.flush()
        data, addr = await asyncio.to_thread(listener.recvfrom, 100)
        assert data == b"hello"
        listener.sendto(b"reply", addr)
        for _ in range(50):
            if got:
                break
            await asyncio.sleep(0.05)
        assert got == [b"reply"] and link._peers == {}  # the reply came from the fixed peer, not a new one
    finally:
        link.close()
        listener.close()
    with pytest.raises(OSError, match=r"cannot resolve 'no-such-host\.invalid'"):
        await UdpLink(parse_endpoint("udpout://no-such-host.invalid:1"), lambda d, n: None).open()

"""Faults against the real ``secuav-proxy`` process: a recording that cannot be written, SIGTERM mid-swap.

A pymavlink vehicle streams numbered DISTANCE_SENSOR frames (``time_boot_ms``
is the number) at 200 Hz; a pymavlink ground station counts what arrives.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import aiomqtt
import pytest
from pymavlink import mavutil

from secuav_common.broker import EmbeddedBroker
from tests.conftest import free_tcp_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]
REPO = Path(__file__).resolve().parents[2]
BIAS = {"name": "plus-1m", "rules": [{"target": {"message": "DISTANCE_SENSOR"}, "kind": "bias", "offset_m": 1.0}]}


def _proxy(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "mitm_proxy", *args], cwd=REPO, stdout=log.open("wb"),
                            stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip


class Stream:
    def __init__(self, vehicle_port: int, gcs_port: int) -> None:
        self.veh = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle_port}", source_system=1, source_component=1)
        self.gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
        self.seq = 0
        self.got: dict[int, int] = {}  # frame number -> range in cm as the ground got it

    async def send(self, n: int) -> None:
        for _ in range(n):
            self.seq += 1
            self.veh.mav.distance_sensor_send(self.seq, 5, 4000, 250, 0, 0, 0, 0)
            self.drain()
            await asyncio.sleep(0.005)

    def drain(self) -> None:
        while (msg := self.gcs.recv_match(type="DISTANCE_SENSOR", blocking=False)) is not None:
            self.got[msg.time_boot_ms] = msg.current_distance

    async def until_flowing(self) -> int:
        """Send until frames come out; the number of the first frame that will be counted."""
        async with asyncio.timeout(30):
            while not self.got:
                await self.send(10)
        await asyncio.sleep(0.1)
        self.drain()
        return self.seq + 1

    def close(self) -> None:
        self.veh.close()
        self.gcs.close()


@pytest.mark.parametrize("trouble", ["disk-full", "unwritable-dir"])
async def test_a_recording_that_cannot_be_written_stops_once_and_forwarding_goes_on(
    trouble: str, tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    if trouble == "disk-full":
        record = tmp_path / "rec"
        (record / "v1").mkdir(parents=True)
        for name in ("original.tlog", "forwarded.tlog", "index.json"):  # every write fails: ENOSPC
            (record / "v1" / name).symlink_to("/dev/full")
    else:
        record = Path("/proc/secuav-no-such-dir")  # cannot be made, not even by root
    profile = tmp_path / "bias.json"
    profile.write_text(json.dumps(BIAS))
    vport, gport = udp_port(), udp_port()
    log = tmp_path / "proxy.log"
    ends = ["--vehicle", f"udpin://127.0.0.1:{vport}", "--ground", f"udpout://127.0.0.1:{gport}"]
    proxy = _proxy(["--broker", "none", "--profile", str(profile), "--record", str(record), *ends], log)
    stream = Stream(vport, gport)
    try:
        first = await stream.until_flowing()
        await stream.send(400)
        await asyncio.sleep(0.3)
        stream.drain()
        counted = {k: v for k, v in stream.got.items() if k >= first}
        assert len(counted) == 400, (len(counted), first, stream.seq)
        assert set(counted.values()) == {350}  # every frame went through the attack stage
    finally:
        stream.close()
        proxy.send_signal(signal.SIGINT)
        code = proxy.wait(15)
    text = log.read_text()
    assert code == 0, text
    assert text.count("record.failed") == 1, text
    assert ("No space left" if trouble == "disk-full" else "No such file") in text
    assert "Traceback" not in text


async def test_sigterm_in_the_middle_of_profile_swaps_stops_cleanly(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()
    vport, gport = udp_port(), udp_port()
    log = tmp_path / "proxy.log"
    async with EmbeddedBroker(port=port):
        proxy = _proxy(["--broker", f"mqtt://127.0.0.1:{port}", "--instance", "swap", "--vehicle",
                        f"udpin://127.0.0.1:{vport}", "--ground", f"udpout://127.0.0.1:{gport}"], log)  # fmt: skip
        stream = Stream(vport, gport)
        try:
            await stream.until_flowing()
            async with aiomqtt.Client("127.0.0.1", port) as client:
                async with asyncio.timeout(20):  # the proxy is on the broker before the swaps start
                    while "mqtt.connected" not in log.read_text():
                        await asyncio.sleep(0.05)
                for i in range(60):
                    body = {**(BIAS if i % 2 == 0 else {}), "request_id": f"swap-{i}"}
                    await client.publish("secuav/v1/attack/set", json.dumps(body).encode(), qos=1)
                    if i == 30:
                        proxy.send_signal(signal.SIGTERM)
                    await stream.send(1)
                code = await asyncio.to_thread(proxy.wait, 15)
                await client.subscribe("secuav/proxy/swap/online")
                async with asyncio.timeout(10):
                    async for message in client.messages:
                        record = json.loads(bytes(message.payload))
                        break
        finally:
            stream.close()
            if proxy.poll() is None:
                proxy.kill()
    text = log.read_text()
    assert code == 0, text
    assert "proxy.stop" in text and "Traceback" not in text, text
    assert record["online"] is False  # said on the way out, retained for whoever looks next

"""Runtime bypass through the real ``secuav-proxy`` process: ``attack/mode/set`` as a user sends it.

A pymavlink "vehicle" streams DISTANCE_SENSOR into the daemon, a pymavlink
ground station reads what comes out, and the attack is switched over a real
broker: a bias profile shows up on the ground, ``bypass`` (the bare word, as
``mosquitto_pub -m bypass`` sends it) takes it away while the profile stays
installed, and ``{"mode": "on"}`` brings it back.
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
from typing import IO

import aiomqtt
import pytest
from pymavlink import mavutil

from secuav_common.broker import EmbeddedBroker
from tests.conftest import free_tcp_port
from tests.support.brokers import attack_cli

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(120), pytest.mark.usefixtures("proxy_path")]
TRUE_CM = 250
BIAS = {"name": "bias", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                   "kind": "bias", "offset": 1.0}]}  # fmt: skip


async def _stream_and_read(vehicle_port: int, gcs: mavutil.mavfile, stop: asyncio.Event, seen: list[int]) -> None:
    veh = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle_port}", source_system=1, source_component=1)
    try:
        while not stop.is_set():
            veh.mav.distance_sensor_send(0, 5, 4000, TRUE_CM, 0, 0, 0, 0)
            while (msg := gcs.recv_match(type="DISTANCE_SENSOR", blocking=False)) is not None:
                seen.append(msg.current_distance)
            await asyncio.sleep(0.01)
    finally:
        veh.close()


async def _request(
    client: aiomqtt.Client, topic: str, payload: bytes, state: str, want: Callable[[dict], bool]
) -> dict:
    await client.subscribe(state)
    async with asyncio.timeout(20):
        # The proxy publishes its (retained) states only after it has subscribed to the requests: wait for one,
        # or a request sent while the proxy is still subscribing is lost (seen on a loaded machine).
        async for message in client.messages:
            if str(message.topic) == state:
                break
        await client.publish(topic, payload, qos=1)
        async for message in client.messages:
            if str(message.topic) == state:
                body = json.loads(message.payload)
                if want(body):
                    return body
    raise AssertionError("unreachable")


def _stop(proxy: subprocess.Popen[bytes], log: IO[bytes]) -> None:
    """SIGINT (what Ctrl-C sends), then kill if it does not stop within 10 s."""
    proxy.send_signal(signal.SIGINT)
    try:
        proxy.wait(10)
    finally:
        if proxy.poll() is None:
            proxy.kill()
        log.close()


async def _settled(seen: list[int], value: int) -> None:
    """Wait until the ground receives ``value`` several times in a row (event-based, generous timeout)."""
    async with asyncio.timeout(20):
        while not (len(seen) >= 5 and all(v == value for v in seen[-5:])):
            await asyncio.sleep(0.02)


async def test_bypass_and_on_over_mqtt_reach_the_wire(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    broker_port, vehicle_port, gcs_port = free_tcp_port(), udp_port(), udp_port()
    async with EmbeddedBroker(port=broker_port):
        log = open(tmp_path / "proxy.log", "wb")  # noqa: SIM115 - the child writes to it until it stops
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", f"mqtt://127.0.0.1:{broker_port}",
             "--vehicle", f"udpin://127.0.0.1:{vehicle_port}", "--ground", f"udpout://127.0.0.1:{gcs_port}"],
            stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
        seen: list[int] = []
        stop = asyncio.Event()
        streamer = asyncio.create_task(_stream_and_read(vehicle_port, gcs, stop, seen))
        try:
            await _settled(seen, TRUE_CM)
            async with aiomqtt.Client("127.0.0.1", broker_port) as client:
                ack = await _request(client, "secuav/v1/attack/set", json.dumps(BIAS).encode(),
                                     "secuav/v1/attack/state", lambda b: b.get("profile") == "bias")  # fmt: skip
                assert ack["ok"]
                await _settled(seen, TRUE_CM + 100)
                ack = await _request(client, "secuav/v1/attack/mode/set", b"bypass",
                                     "secuav/v1/attack/mode/state", lambda b: b.get("mode") == "bypass")  # fmt: skip
                assert ack["ok"], ack
                await _settled(seen, TRUE_CM)
                ack = await _request(client, "secuav/v1/attack/mode/set", b'{"mode": "on", "request_id": "r2"}',
                                     "secuav/v1/attack/mode/state", lambda b: b.get("request_id") == "r2")  # fmt: skip
                assert ack["ok"] and ack["mode"] == "on", ack
                await _settled(seen, TRUE_CM + 100)
            # The same from the command line: secuav-attack mode / secure, answering with the proxy's verdict.
            code, out = await attack_cli("mode", "bypass", "--broker", f"mqtt://127.0.0.1:{broker_port}")
            assert code == 0 and "ok: v1 attack bypass" in out, out
            await _settled(seen, TRUE_CM)
            code, out = await attack_cli("mode", "on", "--vehicle", "1", "--broker", f"mqtt://127.0.0.1:{broker_port}")
            assert code == 0 and "ok: v1 attack on" in out, out
            await _settled(seen, TRUE_CM + 100)
            code, out = await attack_cli("secure", "secekf", "--broker", f"mqtt://127.0.0.1:{broker_port}")
            assert code == 1 and "secure stage is not available" in out, out  # no scenario, no secure stage: said why
        finally:
            stop.set()
            await streamer
            gcs.close()
            _stop(proxy, log)
    assert proxy.returncode in (0, 130), (tmp_path / "proxy.log").read_text()


async def test_secuav_attack_secure_switches_the_estimator(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    broker_port = free_tcp_port()
    async with EmbeddedBroker(port=broker_port):
        log = open(tmp_path / "proxy.log", "wb")  # noqa: SIM115 - the child writes to it until it stops
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", f"mqtt://127.0.0.1:{broker_port}", "--scenario",
             "wall_hover", "--vehicle", f"udpin://127.0.0.1:{udp_port()}", "--ground", f"udpout://127.0.0.1:{udp_port()}"],
            stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            broker = f"mqtt://127.0.0.1:{broker_port}"
            async with aiomqtt.Client("127.0.0.1", broker_port) as client:  # the proxy is up once it says so
                await client.subscribe("secuav/v1/secure/state")
                async with asyncio.timeout(30):
                    async for _message in client.messages:
                        break
            at = ("--broker", broker, "--timeout", "20")
            code, out = await attack_cli("secure", "secekf", "--param", "alpha=0.001", *at)
            assert code == 0 and "ok: v1 secure secekf on the frames toward the ground" in out, out
            code, out = await attack_cli("secure", "secekf", "--direction", "uplink", *at)  # on what the vehicle gets
            assert code == 0 and "ok: v1 secure secekf on the frames toward the vehicle" in out, out
            code, out = await attack_cli("status", *at)
            assert code == 0 and "v1: secure secekf on the frames toward the vehicle" in out, out
            code, out = await attack_cli("secure", "nosuch", "--broker", broker, "--timeout", "20")
            assert code == 1 and "nosuch" in out, out
            code, out = await attack_cli("secure", "off", "--broker", broker, "--timeout", "20")
            assert code == 0 and "ok: v1 secure off" in out, out
        finally:
            _stop(proxy, log)

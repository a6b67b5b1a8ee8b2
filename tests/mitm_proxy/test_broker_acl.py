"""The compose stack's broker accounts and ACL (docker/users.sh, docker/mosquitto.acl) on the real mosquitto.

A real ``secuav-proxy`` logs in as ``proxy`` while a pymavlink vehicle streams
DISTANCE_SENSOR at 50 Hz to a pymavlink ground station. An anonymous client is
turned away at CONNECT; the ``viewer`` and ``sim`` accounts may connect, but
their attack requests are dropped by the broker: the proxy never sees them and
the ground keeps receiving the true range. ``secuav-attack apply`` as
``operator`` is acknowledged and the ground then receives the biased range.
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

from secuav_common.broker import admits
from tests.support.brokers import Mosquitto, attack_cli, needs_mosquitto

pytestmark = [
    pytest.mark.slow,
    pytest.mark.timeout(120),
    pytest.mark.mosquitto,
    needs_mosquitto,
]
REPO = Path(__file__).resolve().parents[2]
BIAS = {"name": "acl-bias", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                       "kind": "bias", "offset_m": 1.0}]}  # fmt: skip


def _accounts(tmp_path: Path) -> Path:
    secrets = tmp_path / "secrets"
    env = {**os.environ, "SECUAV_SECRETS_DIR": str(secrets)}
    subprocess.run(["bash", str(REPO / "docker" / "users.sh")], env=env, check=True, capture_output=True, timeout=60)
    return secrets


async def _ranges_cm(gcs: mavutil.mavfile, seconds: float) -> list[int]:
    """DISTANCE_SENSOR ranges the ground received over ``seconds``."""
    out: list[int] = []
    end = asyncio.get_running_loop().time() + seconds
    while asyncio.get_running_loop().time() < end:
        while (msg := gcs.recv_match(type="DISTANCE_SENSOR", blocking=False)) is not None:
            out.append(msg.current_distance)
        await asyncio.sleep(0.02)
    return out


async def test_anonymous_viewer_and_sim_cannot_change_the_attack_and_the_operator_can(
    tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> None:
    secrets = _accounts(tmp_path)
    pw = {name: (secrets / name).read_text().strip() for name in ("proxy", "sim", "operator", "viewer")}
    assert (secrets / "operator").stat().st_mode & 0o077 == 0
    port = tcp_port()
    acl = REPO / "docker" / "mosquitto.acl"
    extra = f"password_file {secrets / 'mosquitto.passwd'}\nacl_file {acl}\n"
    veh_port, gcs_port = udp_port(), udp_port()
    with Mosquitto(port, tmp_path, extra=extra):
        log = (tmp_path / "proxy.log").open("wb")
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", f"mqtt://127.0.0.1:{port}", "--broker-username", "proxy",
             "--broker-password-file", str(secrets / "proxy"),
             "--vehicle", f"udpin://127.0.0.1:{veh_port}", "--ground", f"udpout://127.0.0.1:{gcs_port}"],
            cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        veh = mavutil.mavlink_connection(f"udpout:127.0.0.1:{veh_port}", source_system=1, source_component=1)
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
        stop = asyncio.Event()

        async def stream() -> None:
            t = 0
            while not stop.is_set():
                t += 20
                veh.mav.distance_sensor_send(t, 10, 4000, 250, 0, 0, 0, 0)
                await asyncio.sleep(0.02)

        sender = asyncio.create_task(stream())
        try:
            async with asyncio.timeout(30):
                while not await _ranges_cm(gcs, 0.3):
                    pass
            assert not await admits("127.0.0.1", port, None, None)
            assert not await admits("127.0.0.1", port, "operator", "not-the-password")

            # The viewer sees the proxy's state but its request never reaches the proxy.
            async with aiomqtt.Client("127.0.0.1", port, username="viewer", password=pw["viewer"]) as viewer:
                await viewer.subscribe("secuav/v1/attack/state")
                for name in ("viewer", "sim"):
                    async with aiomqtt.Client("127.0.0.1", port, username=name, password=pw[name]) as who:
                        await who.publish("secuav/v1/attack/set", json.dumps({**BIAS, "request_id": name}), qos=1)
                answers: list[dict[str, object]] = []
                with pytest.raises(TimeoutError):
                    async with asyncio.timeout(2.0):
                        async for message in viewer.messages:
                            answers.append(json.loads(bytes(message.payload)))
                            if answers[-1].get("request_id") in ("viewer", "sim"):
                                break
                assert all(a.get("request_id") not in ("viewer", "sim") for a in answers), answers
            assert set(await _ranges_cm(gcs, 0.5)) == {250}

            profile = tmp_path / "bias.json"
            profile.write_text(json.dumps(BIAS))
            apply = ("apply", str(profile), "--broker", f"mqtt://127.0.0.1:{port}", "--timeout", "2")
            denied = await attack_cli(*apply, "--username", "viewer", "--password-file", str(secrets / "viewer"))
            assert denied[0] == 3 and "ACL" in denied[1], denied
            assert set(await _ranges_cm(gcs, 0.3)) == {250}
            code, out = await attack_cli(*apply, "--username", "operator", "--password-file", str(secrets / "operator"))
            assert code == 0 and "ok" in out, out
            await _ranges_cm(gcs, 0.2)  # what was in flight
            assert set(await _ranges_cm(gcs, 0.5)) == {350}
        finally:
            stop.set()
            await sender
            veh.close()
            gcs.close()
            proxy.send_signal(signal.SIGINT)
            try:
                assert proxy.wait(15) == 0
            finally:
                if proxy.poll() is None:
                    proxy.kill()
                log.close()

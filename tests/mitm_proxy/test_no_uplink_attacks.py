"""``secuav-proxy --no-uplink-attacks``: a deployment that forbids any change toward the vehicle (issue 33, item 8).

The real daemon as a process, the embedded amqtt broker, the real ``secuav-attack``: a profile with a rule
toward the vehicle is refused at every door (MQTT, the ``--profile`` file reload, ``--profile`` at start, the
config file's ``no_uplink_attacks``) with one line naming the rule, and the profile in force stays.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from attack_profiles import library
from attack_profiles.profile import load_profile
from secuav_common.broker import EmbeddedBroker

pytestmark = pytest.mark.timeout(120)
REPO = Path(__file__).resolve().parents[2]
UPLINK = ("name: feed-lie\nrules:\n  - {target: {message: DISTANCE_SENSOR}, kind: bias, offset: 1}\n"
          "  - {target: {message: DISTANCE_SENSOR, direction: both}, kind: bias, offset: 5}\n")  # fmt: skip


def run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *argv], cwd=REPO, capture_output=True, text=True, timeout=60)


async def attack(*argv: str) -> subprocess.CompletedProcess[str]:
    return await asyncio.to_thread(run, "-m", "mitm_proxy.tools.attack_cli", *argv)


async def state(broker: str) -> dict[str, object]:
    done = await attack("status", "--json", "--vehicle", "1", "--broker", broker)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)["vehicles"]["v1"]["attack/state"]


async def until(check: Callable[[], object], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not await check():  # type: ignore[misc]
        assert time.monotonic() < deadline, "condition not reached"
        await asyncio.sleep(0.2)


async def test_every_door_refuses_a_rule_toward_the_vehicle_and_the_profile_stays(
    tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> None:
    port = tcp_port()
    broker = f"mqtt://127.0.0.1:{port}"
    profile = tmp_path / "attack.yaml"
    profile.write_text(library.text("wall-spoof"), encoding="utf-8")
    kept = load_profile(profile).content_hash()
    uplink = tmp_path / "uplink.yaml"
    uplink.write_text(UPLINK, encoding="utf-8")
    async with EmbeddedBroker(port=port):
        log = tmp_path / "proxy.log"
        with log.open("wb") as sink:
            proxy = subprocess.Popen(
                [sys.executable, "-m", "mitm_proxy", "--no-uplink-attacks", "--broker", broker, "--profile",
                 str(profile), "--vehicle", f"udpin://127.0.0.1:{udp_port()}", "--ground",
                 f"udpout://127.0.0.1:{udp_port()}"],
                cwd=REPO, stdout=sink, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )  # fmt: skip
        try:
            async def up() -> bool:
                return (await attack("status", "--timeout", "1", "--broker", broker)).returncode == 0

            await until(up)
            # MQTT through the real CLI: exit 1, one line naming the rule; wall-spoof stays
            done = await attack("apply", str(uplink), "--vehicle", "1", "--broker", broker)
            assert done.returncode == 1, done.stderr
            (line,) = done.stderr.splitlines()
            assert line.startswith("secuav-attack: v1: rejected: ") and "rules[1].target.direction" in line
            assert "toward the vehicle" in line and "--no-uplink-attacks" in line
            now = await state(broker)
            assert now["hash"] == kept and now["profile"] == "wall-spoof" and now["ok"] is False
            assert now["directions"] == ["downlink"]
            # a profile toward the ground only is still accepted
            done = await attack("apply", "distance-stuck", "--vehicle", "1", "--broker", broker)
            assert done.returncode == 0 and "changing frames toward the ground" in done.stdout, done.stderr
            # the --profile file reload: the edit is refused, distance-stuck stays
            before = (await state(broker))["hash"]
            profile.write_text(UPLINK, encoding="utf-8")

            async def refused() -> bool:
                return (await state(broker))["ok"] is False

            await until(refused)
            now = await state(broker)
            assert now["hash"] == before and "rules[1].target.direction" in str(now["error"])
            assert str(profile) in str(now["error"])
        finally:
            proxy.send_signal(signal.SIGTERM)
            try:
                await asyncio.to_thread(proxy.wait, 10)
            finally:
                if proxy.poll() is None:
                    proxy.kill()
    text = log.read_text()
    assert "uplink_attacks=forbidden" in text and "changes=\"toward the ground\"" in text  # proxy.ready says it


def test_at_start_the_flag_and_the_config_file_refuse_it_in_one_line(tmp_path: Path,
                                                                     udp_port: Callable[[], int]) -> None:  # fmt: skip
    uplink = tmp_path / "uplink.yaml"
    uplink.write_text(UPLINK, encoding="utf-8")
    ends = ["--broker", "none", "--vehicle", f"udpin://127.0.0.1:{udp_port()}", "--ground",
            f"udpout://127.0.0.1:{udp_port()}"]  # fmt: skip
    done = run("-m", "mitm_proxy", "--no-uplink-attacks", "--profile", str(uplink), *ends)
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("secuav-proxy: error: ") and f"{uplink}: rules[1].target.direction" in line
    config = tmp_path / "proxy.yaml"
    config.write_text("no_uplink_attacks: true\n", encoding="utf-8")
    done = run("-m", "mitm_proxy", "--config", str(config), "--profile", str(uplink), *ends)
    assert done.returncode == 2 and "rules[1].target.direction" in done.stderr, done.stderr
    printed = run("-m", "mitm_proxy", "--config", str(config), "--print-config", *ends)
    assert "no_uplink_attacks: true" in printed.stdout, printed.stderr

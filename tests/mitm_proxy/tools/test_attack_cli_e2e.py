"""The user's whole loop, as processes: mosquitto, ``secuav-proxy --profile F``, ``secuav-attack``.

Apply and clear over MQTT, edit the profile file under the running daemon, read
it all back with ``status``, and see ``online`` turn false when the daemon stops.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from attack_profiles import library
from attack_profiles.profile import load_profile
from tests.support.brokers import Mosquitto, needs_mosquitto
from tests.support.frames_support import mavlink, pack

pytestmark = [
    pytest.mark.slow,
    pytest.mark.timeout(120),
    pytest.mark.mosquitto,
    needs_mosquitto,
]
REPO = Path(__file__).resolve().parents[3]


def attack(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mitm_proxy.tools.attack_cli", *argv],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def status(broker: str) -> dict[str, object]:
    done = attack("status", "--json", "--broker", broker)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def wait_until(check: Callable[[], bool], timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.2)


@pytest.fixture
def stack(
    tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> Iterator[tuple[str, Path, subprocess.Popen[bytes], int]]:
    port, vehicle = tcp_port(), udp_port()
    profile = tmp_path / "attack.yaml"
    profile.write_text(library.text("wall-spoof"), encoding="utf-8")
    broker = f"mqtt://127.0.0.1:{port}"
    with Mosquitto(port, tmp_path):
        log = (tmp_path / "proxy.log").open("wb")
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", broker, "--profile", str(profile),
             "--vehicle", f"udpin://127.0.0.1:{vehicle}", "--ground", f"udpout://127.0.0.1:{udp_port()}"],
            cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        try:
            wait_until(lambda: attack("status", "--timeout", "1", "--broker", broker).returncode == 0)
            yield broker, profile, proxy, vehicle
        finally:
            if proxy.poll() is None:
                proxy.send_signal(signal.SIGTERM)
                try:
                    proxy.wait(10)
                except subprocess.TimeoutExpired:
                    proxy.kill()
            log.close()


def test_apply_edit_clear_and_stop_against_the_real_daemon(
    stack: tuple[str, Path, subprocess.Popen[bytes], int],
) -> None:
    broker, profile, proxy, vehicle = stack
    first = status(broker)
    assert first["online"] is True
    v1 = first["vehicles"]["v1"]  # type: ignore[index]
    assert v1["attack/state"]["profile"] == "wall-spoof" and v1["attack/state"]["request_id"] == "--profile"
    assert v1["attack/state"]["directions"] == ["downlink"]
    # wall-spoof targets DISTANCE_SENSOR only: ArduPilot's RANGEFINDER would keep the truth, but no vehicle sent
    # one yet, so nothing is said; once the vehicle sends one, the state says so
    assert v1["attack/state"]["warnings"] == []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.sendto(pack(mavlink.MAVLink_rangefinder_message(4.2, 1.1)), ("127.0.0.1", vehicle))
    wait_until(lambda: any("RANGEFINDER.distance" in w for w in
                           status(broker)["vehicles"]["v1"]["attack/state"]["warnings"]))  # type: ignore[index]

    done = attack("apply", "distance-stuck", "--broker", broker)
    assert done.returncode == 0 and done.stdout.startswith("ok: v1 distance-stuck (hash "), done.stderr
    assert "v1: warning: attack.true_copy: rules[0] rewrite rangefinder distance in DISTANCE_SENSOR" in done.stderr

    # Editing the file under the running daemon: the edit wins and is acknowledged on MQTT.
    profile.write_text(library.text("wall-spoof").replace("default: 0.2", "default: 0.7"), encoding="utf-8")
    edited = load_profile(profile).content_hash()
    wait_until(lambda: status(broker)["vehicles"]["v1"]["attack/state"]["hash"] == edited)  # type: ignore[index]
    profile.write_text("rules: [\n", encoding="utf-8")  # a broken save keeps the edit active
    wait_until(lambda: status(broker)["vehicles"]["v1"]["attack/state"]["ok"] is False)  # type: ignore[index]
    kept = status(broker)["vehicles"]["v1"]["attack/state"]  # type: ignore[index]
    assert kept["hash"] == edited and str(profile) in kept["error"]

    rejected = attack("apply", "anchors-coordinated", "--broker", broker)  # needs a scenario this daemon lacks
    assert rejected.returncode == 1 and "needs a scenario" in rejected.stderr

    cleared = attack("clear", "--broker", broker)
    assert (cleared.returncode, cleared.stdout) == (0, "ok: v1 cleared\n")

    proxy.send_signal(signal.SIGTERM)
    assert proxy.wait(10) == 0
    assert status(broker)["online"] is False  # said on the way out; the states stay retained

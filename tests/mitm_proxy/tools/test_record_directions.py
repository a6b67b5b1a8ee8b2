"""``secuav-record --attack``: says which way the profile changes frames, that a rule toward the vehicle changes
nothing in a recording of what the vehicle sends, and warns about a true copy only once the vehicle sends it."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from tests.support.frames_support import distance, heartbeat, mav, mavlink, pack

RULES = ("name: p\nrules:\n  - {target: {message: DISTANCE_SENSOR, sensor_id: 0, direction: DIR}, kind: bias, "
         "offset: 5}\n")  # fmt: skip


def record(tmp_path: Path, port: int, direction: str, frames: list[bytes]) -> subprocess.CompletedProcess[str]:
    profile = tmp_path / f"{direction}.yaml"
    profile.write_text(RULES.replace("DIR", direction), encoding="utf-8")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mitm_proxy.tools.record", "--listen", f"udpin://127.0.0.1:{port}", "--out",
         str(tmp_path / f"{direction}.tlog"), "--attack", str(profile), "--idle-stop", "1", "--takeoff"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(0.1)
        deadline = time.monotonic() + 20
        while True:  # --takeoff answers the first HEARTBEAT with arm and take off: then it listens
            assert time.monotonic() < deadline and proc.poll() is None
            sock.sendto(pack(heartbeat(), mav()), ("127.0.0.1", port))
            try:
                sock.recv(4096)
                break
            except TimeoutError:
                continue
        for raw in frames:
            sock.sendto(raw, ("127.0.0.1", port))
            time.sleep(0.01)
    out, err = proc.communicate(timeout=30)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_the_recorder_says_the_directions_and_warns_only_about_what_the_vehicle_sends(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    m = mav()
    plain = [pack(distance(cm=300, sensor_id=0, t_ms=1000 + 100 * k), m) for k in range(5)]
    done = record(tmp_path, udp_port(), "downlink", plain)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["directions"] == ["downlink"] and summary["rewritten"] == 5
    assert "attack.true_copy" not in done.stderr  # like flightsim: no RANGEFINDER, nothing to say

    twin = [*plain, pack(mavlink.MAVLink_rangefinder_message(3.0, 1.0), m)]
    done = record(tmp_path, udp_port(), "both", twin)
    assert done.returncode == 0, done.stderr
    said = [ln for ln in done.stderr.splitlines() if "attack.true_copy" in ln]
    assert len(said) == 1 and " WARNING attack.true_copy sysid=1 profile=p warning=" in said[0], done.stderr
    assert "RANGEFINDER.distance" in said[0]
    assert json.loads(done.stdout)["directions"] == ["downlink", "uplink"]

    done = record(tmp_path, udp_port(), "uplink", plain)
    assert done.returncode == 0, done.stderr
    assert "record: rules[0] of p change frames toward the vehicle" in done.stderr
    assert json.loads(done.stdout)["rewritten"] == 0 and "attack.true_copy" not in done.stderr

"""``secuav-demo rangefinder-feed``: the autopilot itself holds its altitude on a companion's rangefinders.

The flightsim variant, short form, with everything real (amqtt broker, secuav-sim, secuav-feed, secuav-proxy,
the MAVSDK controller): the attack on, with the secure stage on the uplink off and on, two flights at once
on port blocks of their own. The verdicts come from the simulator's truth. The ArduPilot variant needs the
SITL binary (CI has none): here only its exit 3 without one; its measured matrix is in docs/ardupilot.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from demos import cli
from study.closed_loop import free_port_block

DEMO = Path(sys.executable).parent / "secuav-demo"
# 13 s scored after 3 s of settling: the attack ramps to +3 m in 12 s (demos/profiles/vehicle-height-lie.yaml)
HOLD_S = 16


def _fly(secure: str, out: Path) -> dict[str, Any]:
    cmd = [
        sys.executable, "-m", "demos", "rangefinder-feed", "--autopilot", "flightsim", "--secure", secure,
        "--seconds", str(HOLD_S), "--settle", "3", "--out", str(out), "--base-port", str(free_port_block()),
        "--no-progress",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stdout + done.stderr
    (case,) = json.loads((out / "report.json").read_text())["cases"].values()
    return case


@pytest.mark.slow
@pytest.mark.xdist_group("flight_stack")  # a whole demo stack (tests/conftest.py)
@pytest.mark.timeout(300)
def test_the_autopilot_follows_the_fed_lie_and_the_uplink_secure_stage_holds_it(tmp_path: Path) -> None:
    with ThreadPoolExecutor(max_workers=2) as pool:
        off, on = pool.map(_fly, ["off", "secekf"], [tmp_path / "secure-off", tmp_path / "secure-on"])
    assert off["case"] == "attack-on_secure-off" and on["case"] == "attack-on_secure-on"
    # Undefended: the autopilot holds 5 m on its own estimate, which reads high by the lie (up to 3 m), so the
    # vehicle truly sinks. Bounds well inside the lie: a third of it at least, by the end of the hold.
    assert off["own_minus_true_m"]["last_10s"] > 1.0
    assert off["distance_error_m"]["max"] > 1.5 and off["min_distance_m"] < 4.0
    assert off["flagged_by_proxy"] == {}  # no secure stage, no estimates
    # With the secure stage on the uplink the autopilot is fed the secure estimate: its altitude stays true
    # (feed noise 2 cm, the filter's lag on take-off transients) and the vehicle holds; id 2 is named.
    assert not on["collided"]
    assert abs(on["own_minus_true_m"]["last_10s"]) < 0.3
    assert on["distance_error_m"]["max"] < 0.5
    assert on["flagged_by_proxy"].get("2", 0.0) > 0.5


def test_ardupilot_without_a_binary_exits_3_with_one_line(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ARDUPILOT_BIN"}
    env["SECUAV_ARDUPILOT_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run([str(DEMO), "rangefinder-feed", "--autopilot", "ardupilot", "--out", str(tmp_path / "out")],
                          env=env, capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == cli.NO_SITL == 3, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no ArduCopter SITL binary at" in lines[0], done.stderr
    assert not (tmp_path / "out").exists()

"""The headline demo, short form: the same wall-hover attack with the secure stage off and on.

Everything is real: amqtt broker, secuav-sim (JSBSim), secuav-proxy, the MAVSDK
controller; only the ports are moved off the port plan so the test can run
beside a user's tools. The verdicts come from the simulator's ground truth.
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from demos.catalog import PORT_SPAN
from tests.conftest import free_port_block

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("flight_stack"), pytest.mark.timeout(400)]


def _fly(attack: str, secure: str, out: Path) -> dict[str, Any]:
    cmd = [
        sys.executable, "-m", "demos", "wall-hover", "--attack", attack, "--secure", secure, "--seconds", "12",
        "--settle", "3", "--param", "rate_per_s=0.4", "--out", str(out), "--base-port", str(free_port_block(PORT_SPAN)),
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (out / "wall_hover.png").stat().st_size > 10_000
    (case,) = json.loads((out / "report.json").read_text())["cases"].values()
    return case


def test_secure_stage_holds_the_wall_distance_that_the_attack_drags_away(tmp_path: Path) -> None:
    """The matrix's four cases, two flights at a time (each on a port block of its own), as --matrix flies them
    one after the other."""
    plan = {(a, s): tmp_path / f"attack-{a}_secure-{s}" for a in ("on", "off") for s in ("on", "off")}
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {
            (a, s): pool.submit(_fly, "wall-spoof-two" if a == "on" else "none", "secekf" if s == "on" else "off", out)
            for (a, s), out in plan.items()
        }
        cases = {key: f.result() for key, f in futures.items()}
    clean, attacked = cases["off", "off"], cases["on", "off"]
    secured, both = cases["off", "on"], cases["on", "on"]
    # Without attack the controller holds the wall distance, with or without the secure stage.
    assert clean["distance_error_m"]["rms"] < 0.15 and secured["distance_error_m"]["rms"] < 0.15
    # Two of five sensors ramping at 0.4 m/s drag the naive mean: metres off, or into the wall.
    assert attacked["collided"] or attacked["distance_error_m"]["max"] > 1.0
    # The secure stage keeps it within the bounds and flags the two attacked sensors.
    assert not both["collided"]
    assert both["distance_error_m"]["rms"] < 0.15 and both["distance_error_m"]["max"] < 0.3
    assert {"0", "2"} <= {k for k, share in both["flagged_by_proxy"].items() if share > 0.5}

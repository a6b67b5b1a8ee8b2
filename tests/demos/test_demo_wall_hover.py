"""The headline demo, short form: the same wall-hover attack with the secure stage off and on.

Everything is real: amqtt broker, secuav-sim (JSBSim), secuav-proxy, the MAVSDK
controller; only the ports are moved off the port plan so the test can run
beside a user's tools. The verdicts come from the simulator's ground truth.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]


def test_secure_stage_holds_the_wall_distance_that_the_attack_drags_away(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    out = tmp_path / "demo"
    cmd = [
        sys.executable, "-m", "demos", "wall-hover", "--matrix", "--seconds", "12", "--settle", "3",
        "--param", "rate_per_s=0.4", "--out", str(out), "--base-port", str(min(udp_port(), 65000)),  # BASE..BASE+21
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=380)
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads((out / "report.json").read_text())
    cases = report["cases"]
    assert set(cases) == {f"attack-{a}_secure-{s}" for a in ("on", "off") for s in ("on", "off")}
    clean, attacked = cases["attack-off_secure-off"], cases["attack-on_secure-off"]
    secured, both = cases["attack-off_secure-on"], cases["attack-on_secure-on"]
    # Without attack the controller holds the wall distance, with or without the secure stage.
    assert clean["distance_error_m"]["rms"] < 0.15 and secured["distance_error_m"]["rms"] < 0.15
    # Two of five sensors ramping at 0.4 m/s drag the naive mean: metres off, or into the wall.
    assert attacked["collided"] or attacked["distance_error_m"]["max"] > 1.0
    # The secure stage keeps it within the bounds and flags the two attacked sensors.
    assert not both["collided"]
    assert both["distance_error_m"]["rms"] < 0.15 and both["distance_error_m"]["max"] < 0.3
    assert {"0", "2"} <= {k for k, share in both["flagged_by_proxy"].items() if share > 0.5}
    assert (out / "wall_hover.png").stat().st_size > 10_000

"""``secuav-demo command-tamper``: a takeoff command and a mission rewritten on their way to the vehicle.

The flightsim variant flies for real (amqtt broker, secuav-sim, secuav-proxy, the pymavlink ground
station), its attack-off and attack-on cases side by side on port blocks of their own, secure stage off
(it does not touch commands; the full matrix and the ArduPilot variant are measured in docs/ardupilot.md).
The verdicts come from the simulator's truth. The ArduPilot variant needs a SITL binary, which CI lacks:
its missing-binary exit is tested here.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from demos.command_tamper import PROFILE, proxy_counts
from demos.controllers.command_tamper import differences, mission
from secuav_common.geo import EARTH_RADIUS_M
from secuav_common.scenario import Home
from study.closed_loop import free_port_block

DEMO = Path(sys.executable).parent / "secuav-demo"
HOME = Home(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)


def _fly(attack: str, out: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "demos", "command-tamper", "--attack", attack, "--secure", "off", "--out", str(out),
           "--base-port", str(free_port_block()), "--no-progress"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    (case,) = json.loads((out / "report.json").read_text())["cases"].values()
    return case


@pytest.mark.slow
@pytest.mark.xdist_group("flight_stack")  # a whole demo stack (tests/conftest.py)
@pytest.mark.timeout(300)
def test_the_vehicle_climbs_and_flies_where_the_attacker_says_while_the_read_back_matches(tmp_path: Path) -> None:
    with ThreadPoolExecutor(max_workers=2) as pool:
        off_f = pool.submit(_fly, "none", tmp_path / "off")
        on_f = pool.submit(_fly, str(PROFILE), tmp_path / "on")
        off, on = off_f.result(), on_f.result()
    # Bounds: flightsim holds a takeoff altitude within ~0.2 m and passes a waypoint within its 0.5 m acceptance
    # radius; 1 m and 4 m leave room for a loaded machine, and the two answers are 7 m and over 13 m apart.
    t = off["takeoff"]
    assert t["asked_m"] == 5.0 and abs(t["settled_true_height_m"] - 5.0) < 1.0 and t["max_true_height_m"] < 6.5
    assert t["outcome"] == "climbed to the height asked"
    m = off["mission"]
    assert m["read_back_equal"] and m["items_compared"] == m["items_sent"] == 3
    assert m["closest_to_sent_m"] < 4.0 and m["closest_to_shifted_m"] > 15.0  # shifted: 20 m N, 10 m E of it
    assert off["rewritten_frames"] == {} and off["proxy_stats"]["uplink"]["rewritten"] == 0
    # The attack: a takeoff to 5 m climbs to 12 m; the waypoint flown is the shifted one; the read-back is the sent.
    t = on["takeoff"]
    assert t["message"] == "COMMAND_INT" and t["attacker_m"] == 12.0
    assert abs(t["settled_true_height_m"] - 12.0) < 1.0 and t["max_true_height_m"] < 13.5
    assert t["outcome"] == "climbed to the attacker's height"
    m = on["mission"]
    assert m["read_back_equal"], m["read_back_differences"]
    assert m["closest_to_shifted_m"] < 4.0 and m["closest_to_sent_m"] > 10.0  # the path passes 13.4 m from it
    assert m["outcome"] == "flew to the shifted waypoint"
    # One takeoff command, the two positioned items (takeoff, waypoint) up and restored on the way down; RTL at 0/0
    # stays. The proxy's own counters agree (nothing else was rewritten, nothing injected).
    assert on["rewritten_frames"] == {"COMMAND_INT uplink": 1, "MISSION_ITEM_INT uplink": 2,
                                      "MISSION_ITEM_INT downlink": 2}  # fmt: skip
    stats = on["proxy_stats"]
    assert (stats["uplink"]["rewritten"], stats["downlink"]["rewritten"]) == (3, 2)
    assert stats["uplink"]["injected"] == stats["downlink"]["injected"] == 0


def test_ardupilot_without_a_binary_is_one_line_and_exit_3(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ARDUPILOT_BIN"}
    env["SECUAV_ARDUPILOT_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run([str(DEMO), "command-tamper", "--autopilot", "ardupilot", "--out", str(tmp_path / "out")],
                          env=env, capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 3, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("secuav-demo: no ArduCopter SITL binary at"), done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("autopilot", "first"), [("ardupilot", 1), ("flightsim", 0)])
def test_the_mission_and_its_comparison(autopilot: str, first: int) -> None:
    items = mission(HOME, autopilot, 0.0, 30.0, 10.0)
    assert [it["command"] for it in items[first:]] == [22, 16, 20]  # takeoff, waypoint, RTL
    assert [it["seq"] for it in items] == list(range(len(items)))
    wp = items[first + 1]
    east = (wp["y"] * 1e-7 - HOME.lon_deg) * math.radians(1) * EARTH_RADIUS_M * math.cos(math.radians(HOME.lat_deg))
    assert wp["x"] == round(HOME.lat_deg * 1e7) and east == pytest.approx(30.0, abs=0.05)
    back = [dict(it) for it in items]
    assert differences(items, back, first) == []
    back[0]["x"] += 1  # ArduPilot's home slot is its own; PX4's item 0 is the takeoff
    assert differences(items, back, first) == ([] if autopilot == "ardupilot" else ["seq 0 x: sent "
                                               f"{items[0]['x']}, read {items[0]['x'] + 1}"])  # fmt: skip
    back[first + 1]["param4"] = math.nan
    assert f"seq {first + 1} param4: sent 0.0, read nan" in differences(items, back, first)
    assert differences(items, back[:-1], first)[0] == f"count: sent {len(items)}, read {len(items) - 1}"


def test_a_parameter_the_profile_does_not_declare_is_refused_before_anything_flies(tmp_path: Path) -> None:
    done = subprocess.run([str(DEMO), "command-tamper", "--param", "north=20", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 1, done
    (line,) = done.stderr.strip().splitlines()
    assert "command-tamper.yaml: north: not a parameter of this profile" in line and "north_m" in line
    assert not (tmp_path / "out").exists()


def test_frames_the_proxy_changed_are_counted_by_message_and_direction_even_from_an_open_index(
    tmp_path: Path,
) -> None:
    """The recording's index.json is a JSON array closed when the proxy stops; a proxy killed leaves it open."""
    entries = [
        {"msgid": 76, "direction": "uplink", "changed": True, "injected": False},
        {"msgid": 73, "direction": "uplink", "changed": True, "injected": False},
        {"msgid": 73, "direction": "downlink", "changed": True, "injected": False},
        {"msgid": 76, "direction": "uplink", "changed": False, "injected": True},  # a forged command: not a rewrite
        {"msgid": 132, "direction": "downlink", "changed": True, "injected": False},  # DISTANCE_SENSOR: not counted
    ]
    index = tmp_path / "index.json"
    index.write_text("[\n" + ",\n".join(json.dumps(e) for e in entries))  # no closing bracket
    side = {"frames_in": 9, "rewritten": 2, "injected": 1, "dropped": 0, "bytes_in": 1}
    got = proxy_counts(index, {"uplink": side, "downlink": side})
    assert got["rewritten_frames"] == {"COMMAND_LONG uplink": 1, "MISSION_ITEM_INT downlink": 1,
                                       "MISSION_ITEM_INT uplink": 1}  # fmt: skip
    assert got["proxy_stats"]["uplink"] == {"frames_in": 9, "rewritten": 2, "injected": 1, "dropped": 0}
    assert proxy_counts(tmp_path / "none.json", None) == {"rewritten_frames": {}, "proxy_stats": None}


def test_the_demo_defaults_go_only_to_a_library_profile_that_declares_them() -> None:
    from demos import cli, command_tamper, formation
    from secuav_common.loading import InputError

    assert cli.attack_params(formation, "anchors-constant", {}) == {"links": [11, 14, 51]}  # formation's default
    assert cli.attack_params(formation, "wall-spoof", {}) == {}  # declares no links: not sent, not refused
    library_file = Path(__file__).resolve().parents[2] / "attack_profiles/library/anchors-constant.yaml"
    assert cli.attack_params(formation, str(library_file), {}) == {}  # a file's own defaults stand
    assert cli.attack_params(command_tamper, str(PROFILE), {"east_m": -5}) == {"east_m": -5}
    with pytest.raises(InputError, match="north: not a parameter of this profile"):
        cli.attack_params(command_tamper, str(PROFILE), {"north": 3})

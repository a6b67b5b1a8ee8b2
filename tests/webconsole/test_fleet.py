"""The console's fleet model, sans I/O: what it keeps per vehicle and what it computes for the plots."""

from __future__ import annotations

import math

from secuav_common.scenario import load_scenario
from webconsole.fleet import HISTORY, Fleet


def test_anchor_readings_get_truth_and_the_secure_estimates_implied_range() -> None:
    scenario = load_scenario("anchors8")
    fleet = Fleet([scenario])
    anchor = scenario.world.anchors[2]
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": None, "ok": True}, now=1.0)
    fleet.on_message("secuav/v1/truth", {"pos_ned_m": [1.0, 2.0, -3.0]}, now=1.1)
    fleet.on_message("secuav/v1/estimate", {"estimator": "secekf", "position_ned_m": [1.5, 2.0], "attacked": [12]},
                     now=1.2)  # fmt: skip
    fleet.on_message("secuav/v1/readings", {"sensors": {str(10 + anchor.id): {"original_m": 5.0, "forwarded_m": 6.0,
                                                                               "flagged": True}}}, now=1.3)  # fmt: skip
    samples = fleet.vehicles[1].since(0)
    assert [s["kind"] for s in samples] == ["truth", "estimate", "readings"]
    reading = samples[-1]["sensors"][str(10 + anchor.id)]
    assert reading["truth_m"] == math.dist([1.0, 2.0, -3.0], anchor.pos_ned_m)
    assert reading["secure_m"] == math.dist([1.5, 2.0, -3.0], anchor.pos_ned_m)  # 2-D estimate, true height
    assert reading["flagged"] and reading["forwarded_m"] == 6.0
    assert fleet.vehicles[1].since(samples[1]["seq"]) == samples[2:]


def test_streams_alone_make_no_vehicle_history_is_bounded_and_junk_is_ignored() -> None:
    fleet = Fleet()
    fleet.on_message("secuav/v3/truth", {"pos_ned_m": [0, 0, 0]})
    assert fleet.vehicles == {}  # a simulator without a proxy: nothing to steer
    fleet.on_message("secuav/v3/stats", {"downlink": {"frames_in": 1}})
    for i in range(HISTORY + 10):
        fleet.on_message("secuav/v3/truth", {"pos_ned_m": [i, 0.0, 0.0]}, now=float(i))
    view = fleet.vehicles[3]
    assert len(view.samples) == HISTORY and view.samples[0]["pos"][0] == 10.0
    assert len(view.since(0, not_before_t=HISTORY + 5.0)) == 5
    for topic, body in [("secuav/v3/truth", {"pos_ned_m": [float("nan"), 0, 0]}), ("secuav/v300/stats", {}),
                        ("secuav/vx/stats", {}), ("other/v1/stats", {}), ("secuav/v3/stats", [1, 2])]:  # fmt: skip
        fleet.on_message(topic, body)
    assert list(fleet.vehicles) == [3] and len(view.samples) == HISTORY  # the NaN truth was not kept
    row = fleet.summary()[0]
    assert row["sysid"] == 3 and not row["online"]  # no proxy instance record says it serves v3


def test_a_vehicle_leaves_the_fleet_when_its_proxy_is_gone() -> None:
    fleet = Fleet()
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": None, "ok": True})  # retained, proxy long gone
    assert fleet.summary() == []
    fleet.on_message("secuav/proxy/lab/online", {"instance": "lab", "online": True, "vehicles": [1]})
    fleet.on_message("secuav/v1/stats", {"downlink": {"frames_in": 5}})
    assert [r["sysid"] for r in fleet.summary()] == [1] and fleet.summary()[0]["online"]
    fleet.on_message("secuav/proxy/lab/online", {"instance": "lab", "online": False, "vehicles": [1]})
    row = fleet.summary()[0]
    assert not row["online"]  # just stopped: shown offline until its stats are GONE_S old
    fleet.vehicles[1].stats_at = -1e9
    assert fleet.summary() == []


def test_the_states_warnings_reach_the_vehicle_row_and_clear_with_them() -> None:
    """A stage that cannot work says so in its state (issue 27); the console's row carries it for the page."""
    fleet = Fleet()
    fleet.on_message("secuav/proxy/lab/online", {"instance": "lab", "online": True, "vehicles": [1]})
    fleet.on_message("secuav/v1/stats", {"downlink": {"frames_in": 5}})
    assert fleet.summary()[0]["warnings"] == []
    signed = "attack.signed_no_key: system 1 signs its frames ... --signing-key FILE"
    layout = "secure.layout_mismatch: scenario 'wall-hover' gives vehicle 1 ..."
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": "bias", "warnings": [signed]})
    fleet.on_message("secuav/v1/secure/state", {"sysid": 1, "estimator": "secekf", "warnings": [layout]})
    assert fleet.summary()[0]["warnings"] == [signed, layout]
    fleet.on_message("secuav/v1/secure/state", {"sysid": 1, "estimator": "secekf", "warnings": []})
    assert fleet.summary()[0]["warnings"] == [signed]
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": "bias"})  # an older proxy: no field
    assert fleet.summary()[0]["warnings"] == []


def test_the_row_says_which_way_the_profile_and_the_secure_stage_act() -> None:
    fleet = Fleet()
    fleet.on_message("secuav/proxy/lab/online", {"instance": "lab", "online": True, "vehicles": [1]})
    fleet.on_message("secuav/v1/stats", {"downlink": {"frames_in": 5}})
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": "bias"})  # an older proxy: no field
    assert fleet.summary()[0]["directions"] == [] and fleet.summary()[0]["secure_direction"] is None
    fleet.on_message("secuav/v1/attack/state", {"sysid": 1, "profile": "feed", "directions": ["uplink"]})
    fleet.on_message("secuav/v1/secure/state", {"sysid": 1, "estimator": "secekf", "direction": "uplink"})
    row = fleet.summary()[0]
    assert row["directions"] == ["uplink"] and row["secure_direction"] == "uplink"

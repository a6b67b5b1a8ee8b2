"""Live frames and offline arrays run the one rule chain: every library attack on ranges gives the same values both
ways (the offline evaluation measures the attack the proxy applies), including those that read the vehicle's position
as the attacker sees it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from attack_profiles import Direction, Engine, library
from attack_profiles.units import LOCAL_POSITION_NED_ID, MESSAGES
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario, load_scenario

RATE_HZ = 10.0
IDS = [*range(10, 18), 0]  # the eight anchor links and the downward laser
DISTANCE_SENSOR_ID = MESSAGES["DISTANCE_SENSOR"].msgid


# Delay shows an earlier value offline but holds the frame back live: the one kind that differs by design.
def _on_anchors8(name: str) -> bool:
    try:
        Engine(library.load(name), scenario=load_scenario("anchors8"))
    except InputError:  # a wall-scenario attack
        return False
    return True


SAME_BOTH_WAYS = [
    name
    for name in library.names(plugins=False)  # the bundled library (a plugin's primitives are its own to test)
    if library.load(name).rules
    and all(
        r.target.message == "DISTANCE_SENSOR"
        and r.kind not in ("delay", "intermittent", "drop")
        and r.target.direction != "uplink"  # offline arrays are the ground's view (vehicle-rangefinder-bias is not)
        for r in library.load(name).rules
    )
    and _on_anchors8(name)
]


@pytest.fixture(scope="module")
def anchors8() -> Scenario:
    return load_scenario("anchors8")


def _stream(scenario: Scenario, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A vehicle circling at 2.5 m (its own estimate, what the attacker reads) and the ranges it measures, to the cm."""
    anchors = scenario.anchor_positions()
    t = (np.arange(n) + 1) / RATE_HZ
    pos = np.stack([2.5 + np.cos(0.2 * t), 2.5 + np.sin(0.2 * t), np.full(n, -2.5)], axis=1)
    z = np.array([[math.dist(p, anchors[k]) for k in range(8)] + [2.5] for p in pos])
    return t, np.round(z * 100.0) / 100.0, pos


def test_the_library_has_range_attacks_to_compare() -> None:
    assert {"anchors-mirror", "anchors-coordinated", "anchors-stealthy", "height-spoof", "type-a"} <= set(
        SAME_BOTH_WAYS
    )


@pytest.mark.parametrize("name", SAME_BOTH_WAYS)
def test_live_and_offline_agree(name: str, anchors8: Scenario) -> None:
    t, z, pos = _stream(anchors8, 300)
    profile = library.load(name)
    offline = Engine(profile, seed=3, scenario=anchors8).apply_array(t, z, IDS, position_ned_m=pos)

    live_engine = Engine(profile, seed=3, scenario=anchors8)
    live_engine.activate(0.0)
    live = np.full_like(z, np.nan)
    for k, t_k in enumerate(t):
        boot_ms = round(t_k * 1000)
        x, y, d = pos[k]
        live_engine.process(
            t_k, LOCAL_POSITION_NED_ID, {"time_boot_ms": boot_ms, "x": x, "y": y, "z": d}, Direction.DOWNLINK, 1, 1
        )
        for j, sid in enumerate(IDS):
            cm = round(z[k, j] * 100)
            fields = {"time_boot_ms": boot_ms, "id": sid, "current_distance": cm}
            action = live_engine.process(t_k, DISTANCE_SENSOR_ID, fields, Direction.DOWNLINK, 1, 1)
            if action.drop:
                continue
            live[k, j] = (action.fields or {}).get("current_distance", cm) / 100.0
    assert np.any(np.abs(offline - z) > 0.01), f"{name} changed nothing offline"
    # Live carries centimetres on the wire; offline keeps the physical value.
    np.testing.assert_allclose(live, offline, atol=0.005 + 1e-9, equal_nan=True)

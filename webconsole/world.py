"""The scenario geometry the console draws, and what each sensor would read in truth.

Everything here is the console's own arithmetic on the scenario file (walls,
anchors, the vehicles' sensors): the proxy and the estimators never see it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from secuav_common.scenario import Scenario, Vehicle
from secuav_common.sensor_ids import ANCHOR_BASE, PEER_BASE  # wall sensors 0-9, anchor k at 10+k, peer n at 50+n


def world_json(scenario: Scenario) -> dict[str, Any]:
    """What the page's top view needs: walls, anchors, and each vehicle's start, target and sensors."""
    return {
        "name": scenario.name,
        "walls": [{"name": w.name, "point_ned_m": list(w.point_ned_m), "normal_ned": list(w.normal_ned)}
                  for w in scenario.world.walls],
        "anchors": [{"id": a.id, "pos_ned_m": list(a.pos_ned_m)} for a in scenario.world.anchors],
        "vehicles": {str(v.sysid): _vehicle(v, [a.id for a in scenario.world.anchors]) for v in scenario.vehicles},
    }  # fmt: skip


def _vehicle(v: Vehicle, anchors: list[int]) -> dict[str, Any]:
    target = v.target.model_dump(mode="json") if v.target is not None else None
    return {"name": v.name, "start_ned_m": list(v.start.pos_ned_m), "target": target,
            "sensors": sensor_names(v, anchors)}  # fmt: skip


def sensor_names(v: Vehicle, anchors: list[int]) -> dict[str, str]:
    """DISTANCE_SENSOR id -> what it is (``"0": "laser forward"``, ``"12": "UWB anchor 2"``)."""
    names = {str(r.id): f"{r.type} {r.orientation}" for r in v.sensors.rangefinders}
    if v.sensors.uwb is not None:
        for k in v.sensors.uwb.anchors if isinstance(v.sensors.uwb.anchors, list) else anchors:
            names[str(ANCHOR_BASE + k)] = f"UWB anchor {k}"
    if v.sensors.inter_vehicle is not None:
        for n in v.sensors.inter_vehicle.peers:
            names[str(PEER_BASE + n)] = f"range to v{n}"
    return names


def true_reading(scenario: Scenario, sysid: int, sensor: int, pos: Sequence[float],
                 peers: dict[int, Sequence[float]]) -> float | None:  # fmt: skip
    """What sensor ``sensor`` of vehicle ``sysid`` would read at true position ``pos`` (NED, m), noise-free."""
    if sensor >= PEER_BASE:
        other = peers.get(sensor - PEER_BASE)
        return None if other is None else _dist(pos, other)
    if sensor >= ANCHOR_BASE:
        anchor = next((a for a in scenario.world.anchors if a.id == sensor - ANCHOR_BASE), None)
        return None if anchor is None else _dist(pos, anchor.pos_ned_m)
    vehicle = next((v for v in scenario.vehicles if v.sysid == sysid), None)
    finder = None if vehicle is None else next((r for r in vehicle.sensors.rangefinders if r.id == sensor), None)
    if finder is None:
        return None
    if finder.orientation == "down":
        return max(0.0, -pos[2])
    gaps = [sum((p - q) * n for p, q, n in zip(pos, w.point_ned_m, w.normal_ned, strict=True))
            for w in scenario.world.walls]  # fmt: skip
    ahead = [g for g in gaps if g >= 0]
    return min(ahead) if ahead else None


def secure_reading(scenario: Scenario | None, sensor: int, estimate: dict[str, Any],
                   height_m: float | None) -> float | None:  # fmt: skip
    """What the secure estimate implies sensor ``sensor`` should read (its distance, or the range to an anchor)."""
    if "distance_m" in estimate and sensor < ANCHOR_BASE:
        value = estimate.get("distance_m")
        return value if isinstance(value, int | float) else None
    pos = estimate.get("position_ned_m")
    if scenario is None or not isinstance(pos, list) or not ANCHOR_BASE <= sensor < PEER_BASE:
        return None
    if any(not isinstance(v, int | float) for v in pos):
        return None
    full = list(pos) if len(pos) == 3 else [*pos, -(height_m or 0.0)]
    anchor = next((a for a in scenario.world.anchors if a.id == sensor - ANCHOR_BASE), None)
    return None if anchor is None else _dist(full, anchor.pos_ned_m)


def _dist(a: Sequence[float], b: Sequence[float]) -> float:
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b, strict=False)))

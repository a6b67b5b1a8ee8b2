"""Small builders shared by the attack_profiles tests (imported as a plain module)."""

from __future__ import annotations

from typing import Any

from attack_profiles import Action, Direction, Engine, Profile, parse_profile

DISTANCE_SENSOR = 132
LOCAL_POSITION_NED = 32
GLOBAL_POSITION_INT = 33
GPS_RAW_INT = 24


def make_profile(*rules: dict[str, Any], clock: str = "activation", seed: int = 0) -> Profile:
    return parse_profile({"name": "test", "clock": clock, "seed": seed, "rules": list(rules)}, "test.yaml")


def rule(kind: str, sensor_id: Any = 0, message: str = "DISTANCE_SENSOR", **params: Any) -> dict[str, Any]:
    """A rule dict; target keys (field, direction, sysid, where) may be given with a ``target_`` prefix."""
    target: dict[str, Any] = {"message": message}
    if sensor_id is not None:
        target["sensor_id"] = sensor_id
    for key in ("field", "direction", "sysid", "where"):
        if f"target_{key}" in params:
            target[key] = params.pop(f"target_{key}")
    return {"target": target, "kind": kind, **params}


def distance(sensor_id: int, cm: int, time_boot_ms: int = 0) -> dict[str, Any]:
    """A DISTANCE_SENSOR field dict as pymavlink decodes it."""
    return {
        "time_boot_ms": time_boot_ms,
        "min_distance": 10,
        "max_distance": 4000,
        "current_distance": cm,
        "type": 0,
        "id": sensor_id,
        "orientation": 0,
        "covariance": 0,
        "horizontal_fov": 0.0,
        "vertical_fov": 0.0,
        "quaternion": [0.0, 0.0, 0.0, 0.0],
        "signal_quality": 0,
    }


def send(
    engine: Engine,
    t_s: float,
    fields: dict[str, Any],
    msgid: int = DISTANCE_SENSOR,
    sysid: int = 1,
    direction: Direction = Direction.DOWNLINK,
) -> Action:
    return engine.process(t_s, msgid, fields, direction, sysid, 1)


def attacked_cm(engine: Engine, t_s: float, sensor_id: int, cm: int) -> int | None:
    """The current_distance the ground sees (None: dropped)."""
    action = send(engine, t_s, distance(sensor_id, cm))
    if action.drop:
        return None
    return (action.fields or {}).get("current_distance", cm)


def started(profile: Profile, **kwargs: Any) -> Engine:
    engine = Engine(profile, **kwargs)
    engine.activate(0.0)
    return engine

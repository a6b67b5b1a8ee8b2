"""DISTANCE_SENSOR id plan of docs/interfaces.md, in one place.

- 0-9: rangefinders toward walls/obstacles (a redundant group shares a target)
- 10-49: UWB anchor k -> id 10 + k
- 50-99: inter-vehicle range to peer sysid n -> id 50 + n
"""

from __future__ import annotations

from enum import IntEnum

MAX_RANGEFINDERS = 10
ANCHOR_BASE = 10
MAX_ANCHORS = 40
PEER_BASE = 50
MAX_PEER_SYSID = 49


class SensorKind(IntEnum):
    RANGEFINDER = 0
    ANCHOR = 1
    PEER = 2


def anchor_sensor_id(anchor_id: int) -> int:
    if not 0 <= anchor_id < MAX_ANCHORS:
        raise ValueError(f"anchor id {anchor_id} outside 0..{MAX_ANCHORS - 1}")
    return ANCHOR_BASE + anchor_id


def peer_sensor_id(peer_sysid: int) -> int:
    if not 0 <= peer_sysid <= MAX_PEER_SYSID:
        raise ValueError(f"peer sysid {peer_sysid} outside 0..{MAX_PEER_SYSID}")
    return PEER_BASE + peer_sysid


def classify(sensor_id: int) -> tuple[SensorKind, int]:
    """Return the kind of a sensor id and its index (rangefinder id, anchor id or peer sysid)."""
    if 0 <= sensor_id < MAX_RANGEFINDERS:
        return SensorKind.RANGEFINDER, sensor_id
    if ANCHOR_BASE <= sensor_id < ANCHOR_BASE + MAX_ANCHORS:
        return SensorKind.ANCHOR, sensor_id - ANCHOR_BASE
    if PEER_BASE <= sensor_id <= PEER_BASE + MAX_PEER_SYSID:
        return SensorKind.PEER, sensor_id - PEER_BASE
    raise ValueError(f"sensor id {sensor_id} is outside the plan (0-99)")


# MAV_SENSOR_ORIENTATION values for the mount directions a scenario names.
ORIENTATION = {"forward": 0, "right": 2, "backward": 4, "left": 6, "up": 24, "down": 25}
# The same mount directions as unit vectors in the body frame (forward, right, down): where each beam points.
MOUNT_BODY: dict[str, tuple[float, float, float]] = {
    "forward": (1.0, 0.0, 0.0),
    "backward": (-1.0, 0.0, 0.0),
    "right": (0.0, 1.0, 0.0),
    "left": (0.0, -1.0, 0.0),
    "up": (0.0, 0.0, -1.0),
    "down": (0.0, 0.0, 1.0),
}
ORIENTATION_CUSTOM = 100
ORIENTATION_DOWN = ORIENTATION["down"]  # MAV_SENSOR_ROTATION_PITCH_270: a height sensor
# DISTANCE_SENSOR.signal_quality: 0 "unknown" (sent with "no target" too), 1 "invalid signal" (what
# secuav-proxy --secure sets on a reading it judges attacked), 100 "perfect".
QUALITY_UNKNOWN = 0
QUALITY_INVALID = 1
# MAV_DISTANCE_SENSOR values.
SENSOR_TYPE = {"laser": 0, "ultrasound": 1, "infrared": 2, "radar": 3}
SENSOR_TYPE_UNKNOWN = 4

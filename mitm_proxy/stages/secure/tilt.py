"""A wall group's readings as distances along the wall's normal: each beam tilted by the vehicle's attitude.

A rangefinder measures along its beam. A multirotor pitches to move (20 degrees
and more on the wall demo's approach), and its forward beams then meet the wall
at ``d / cos``: honest readings swing by 0.3-0.4 m at 5 m while the distance
itself changes smoothly, faster than a filter of the distance can follow, and
the filters judged every sensor attacked. Projected on the wall's normal with
ATTITUDE, each reading is the distance again::

    d = r * (R(roll, pitch, yaw) b) . (-n)

with ``b`` the beam in the body frame (from the sensor's MAV_SENSOR_ORIENTATION)
and ``n`` the wall's unit normal toward the vehicle (the scenario's). The same
holds for downward beams over the ground (``n`` up). A beam more than 60 degrees
off the normal (factor under :data:`MIN_FACTOR`) is not projected: its reading
counts as missing. What the ground gets back is the along-beam range an honest
sensor would show at the current attitude, ``d / factor``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from secuav_common.sensor_ids import MOUNT_BODY, ORIENTATION

MIN_FACTOR = 0.5  # cos 60 degrees
# Body-frame beam (forward, right, down) of each MAV_SENSOR_ORIENTATION a scenario can name.
BEAM_BODY: dict[int, tuple[float, float, float]] = {ORIENTATION[name]: MOUNT_BODY[name] for name in ORIENTATION}


def body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The rotation of a body-frame vector into NED for MAVLink's ATTITUDE angles (yaw, then pitch, then roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def factors(beams_body: np.ndarray, normal_ned: np.ndarray, roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Per beam, the cosine between it and the wall's inward normal at this attitude; NaN past 60 degrees."""
    along = (beams_body @ body_to_ned(roll, pitch, yaw).T) @ -np.asarray(normal_ned, dtype=float)
    return np.where(along >= MIN_FACTOR, along, np.nan)


def attitude(fields: dict[str, Any]) -> tuple[float, float, float] | None:
    """ATTITUDE's (roll, pitch, yaw) in radians, or None when a field is missing or not finite."""
    angles = [fields.get(k) for k in ("roll", "pitch", "yaw")]
    if all(isinstance(a, float) and math.isfinite(a) for a in angles):
        return angles[0], angles[1], angles[2]  # type: ignore[return-value]
    return None


@dataclass(frozen=True, eq=False)
class Geometry:
    """A wall group's beams (p x 3, body frame) and the wall's inward normal (NED): what :func:`factors` needs."""

    beams_body: np.ndarray
    normal_ned: np.ndarray

    @classmethod
    def of(cls, orientations: list[int], normal_ned: tuple[float, float, float] | None) -> Geometry | None:
        """None when the wall has no normal or a sensor's orientation is not one :data:`BEAM_BODY` knows."""
        if normal_ned is None or any(o not in BEAM_BODY for o in orientations):
            return None
        return cls(np.array([BEAM_BODY[o] for o in orientations]), np.asarray(normal_ned, dtype=float))

    def factors(self, roll: float, pitch: float, yaw: float) -> np.ndarray:
        return factors(self.beams_body, self.normal_ned, roll, pitch, yaw)

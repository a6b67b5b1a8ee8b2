"""World geometry: the scenario's wall planes, flat ground at z = 0, collisions.

Everything is in the scenario frame (local NED, metres, origin at home). Walls
are infinite planes whose normal points into the free side; the ground is the
plane ``z = 0`` with its free side up (negative z).

A vehicle is treated as a sphere of ``VEHICLE_RADIUS_M`` around its centre of
gravity for wall contact (an F450's arms and props reach about that far). It
crashes when that sphere touches a wall or another vehicle's, when it meets the ground descending
faster than ``HARD_LANDING_M_S``, or when it is upside down (tilt over 90 deg)
or tipped over on the ground (tilt over 60 deg while in contact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from flightsim.control.rotation import Vec3
from secuav_common.scenario import World as WorldConfig

VEHICLE_RADIUS_M = 0.25
HARD_LANDING_M_S = 2.0
NEAR_GROUND_M = 0.3  # gear contact is only possible this close to z = 0 (the CG sits 0.15 m up)
FLIP_TILT_RAD = math.radians(90.0)
TIPPED_TILT_RAD = math.radians(60.0)
GROUND_NAME = "ground"


@dataclass(frozen=True, slots=True)
class Plane:
    name: str
    point: Vec3
    normal: Vec3  # unit, into the free side

    def signed_distance(self, p: Vec3) -> float:
        """Distance of ``p`` from the plane, positive on the free side."""
        n, a = self.normal, self.point
        return n[0] * (p[0] - a[0]) + n[1] * (p[1] - a[1]) + n[2] * (p[2] - a[2])

    def ray_hit(self, origin: Vec3, direction: Vec3) -> float:
        """Distance along a unit ray from ``origin`` to this plane's free face, or inf.

        Only hits from the free side count: a ray leaving the plane, parallel to
        it, or starting behind it sees nothing of it.
        """
        n = self.normal
        approach = n[0] * direction[0] + n[1] * direction[1] + n[2] * direction[2]
        if approach >= -1e-12:
            return math.inf
        dist = self.signed_distance(origin)
        if dist < 0:
            return math.inf
        return dist / -approach


GROUND = Plane(GROUND_NAME, (0.0, 0.0, 0.0), (0.0, 0.0, -1.0))


@dataclass(frozen=True, slots=True)
class Collision:
    what: str  # a wall's name, "ground", or "flip"
    speed_m_s: float

    @property
    def text(self) -> str:
        if self.what == GROUND_NAME:
            return f"collision with the ground at {self.speed_m_s:.1f} m/s"
        if self.what == "flip":
            return "vehicle flipped over"
        return f"collision with wall '{self.what}' at {self.speed_m_s:.1f} m/s"


class World:
    """The static geometry vehicles fly in."""

    def __init__(self, config: WorldConfig) -> None:
        self.walls = [Plane(w.name, w.point_ned_m, w.normal_ned) for w in config.walls]
        self.planes = [*self.walls, GROUND]

    def raycast(self, origin: Vec3, direction: Vec3) -> tuple[float, str | None]:
        """Nearest surface (walls or ground) along a unit ray: (distance m, name) or (inf, None)."""
        best, name = math.inf, None
        for plane in self.planes:
            d = plane.ray_hit(origin, direction)
            if d < best:
                best, name = d, plane.name
        return best, name

    def check_collision(self, pos: Vec3, vel: Vec3, cos_tilt: float, on_ground: bool) -> Collision | None:
        """The crash this state amounts to, if any; ``cos_tilt`` is body z . NED down."""
        for wall in self.walls:
            if wall.signed_distance(pos) < VEHICLE_RADIUS_M:
                return Collision(wall.name, _norm(vel))
        if on_ground and vel[2] > HARD_LANDING_M_S:
            return Collision(GROUND_NAME, vel[2])
        if cos_tilt < _COS_FLIP or (on_ground and cos_tilt < _COS_TIPPED):
            return Collision("flip", _norm(vel))
        return None

    @staticmethod
    def vehicles_touch(a: Vec3, b: Vec3) -> bool:
        """Two vehicles' spheres overlap (their props would meet)."""
        return (a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2 < (2 * VEHICLE_RADIUS_M) ** 2


_COS_FLIP = math.cos(FLIP_TILT_RAD)
_COS_TIPPED = math.cos(TIPPED_TILT_RAD)


def _norm(v: Vec3) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])

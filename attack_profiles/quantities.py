"""Physical quantities a profile may target, and every message field that carries each.

A sensor attack that rewrites one message leaves the truth in its twins: ArduPilot
sends its downward rangefinder both in DISTANCE_SENSOR and in its own RANGEFINDER
(#173), and a vehicle's height travels in a dozen messages. A rule whose target
names a ``quantity`` instead of a ``message`` is applied to every carrier below
with the same value in the quantity's own unit (metres), converted per carrier:

- ``rangefinder`` (``distance``): DISTANCE_SENSOR by its ``id``, and RANGEFINDER,
  which carries ArduPilot's primary downward rangefinder (the lowest-id
  DISTANCE_SENSOR with orientation 25, pitch 270, that the vehicle has sent;
  id 0 until one was seen), so a rule for that id rewrites it too.
- ``altitude`` (``up``, metres up): every height of the vehicle in any datum
  (AMSL, home, local origin, ellipsoid, terrain) moves by the same amount; NED
  ``z`` fields move by minus that.
- ``position`` (``north``, ``east``, metres): local ``x``/``y`` move by the
  offset, latitudes and longitudes by the offset converted on a sphere of the
  WGS-84 equatorial radius at the message's own latitude (1e-7 degrees is 1.1 cm
  on the wire).

Offsets that depend only on time (bias, ramp, sinusoid) are the same in every
carrier at the same moment; noise draws afresh per frame and carrier; freeze,
replay and delay keep their state per carrier. On ``altitude`` and ``position``
only such relative rules and frame rules are allowed: ``set``, ``scale`` and
``garbage`` would put each datum somewhere else. Frame rules (drop, delay,
intermittent) act on every carrier message of the quantity.

A +5 m lie on ArduPilot's downward rangefinder 0, in DISTANCE_SENSOR and RANGEFINDER alike::

    rules:
      - target: {quantity: rangefinder, sensor_id: 0}
        kind: bias
        offset: 5
      - target: {quantity: position, field: north}
        kind: ramp
        rate_per_s: 0.1

What still reveals a quantity and is not rewritten is listed below the table. A
profile that leaves any carrier of an attacked quantity true on the wire (a
message target with twins, or a quantity with uncovered carriers) is warned
about when it is validated (``secuav-attack validate``, on stderr, as a condition:
"if the vehicle sends it") and, in the proxy, once the vehicle is seen sending such a
carrier (the proxy's log, event ``attack.true_copy``, and ``warnings`` in
``secuav/v<N>/attack/state``). Rules toward the vehicle leave no true twin: the
autopilot reports the lie it was fed (see Directions, below).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    pass

QuantityName = Literal["rangefinder", "altitude", "position"]
QUANTITY_NAMES: tuple[str, ...] = ("rangefinder", "altitude", "position")
COMPONENTS: dict[str, tuple[str, ...]] = {
    "rangefinder": ("distance",),
    "altitude": ("up",),
    "position": ("north", "east"),
}
DEFAULT_COMPONENT: dict[str, str | None] = {"rangefinder": "distance", "altitude": "up", "position": None}
# Rules that set or scale a value, or replace it with garbage, mean something only in one datum:
# on a height or a position they would place each carrier at a different point.
DATUM_QUANTITIES = frozenset({"altitude", "position"})

EARTH_RADIUS_M = 6378137.0  # WGS-84 equatorial radius
M_PER_DEG = EARTH_RADIUS_M * math.pi / 180.0


@dataclass(frozen=True, slots=True)
class Carrier:
    """One message field that carries (a component of) a quantity.

    component (metres) = field value in its physical unit * ``factor``
    (times cos(latitude) for a longitude, ``lat_field`` naming the latitude).
    """

    quantity: str
    component: str
    message: str
    field: str
    factor: float = 1.0
    dialect: str = "common"  # "common": PX4 and ArduPilot alike; "ardupilotmega": ArduPilot only
    lat_field: str | None = None
    sensor: Literal["id", "primary"] | None = None  # how the carrier says which rangefinder it is


def _c(q: str, comp: str, msg: str, fields: str, factor: float = 1.0, **kw: object) -> list[Carrier]:
    return [Carrier(q, comp, msg, f, factor, **kw) for f in fields.split()]  # type: ignore[arg-type]


_AP = {"dialect": "ardupilotmega"}
_ALTITUDES = "altitude_monotonic altitude_amsl altitude_local altitude_relative altitude_terrain bottom_clearance"

CARRIERS: tuple[Carrier, ...] = tuple(
    [
        *_c("rangefinder", "distance", "DISTANCE_SENSOR", "current_distance", sensor="id"),
        *_c("rangefinder", "distance", "RANGEFINDER", "distance", sensor="primary", **_AP),
        *_c("altitude", "up", "GLOBAL_POSITION_INT", "alt relative_alt"),
        *_c("altitude", "up", "LOCAL_POSITION_NED", "z", -1.0),
        *_c("altitude", "up", "ODOMETRY", "z", -1.0),
        *_c("altitude", "up", "VFR_HUD", "alt"),
        *_c("altitude", "up", "ALTITUDE", _ALTITUDES),
        *_c("altitude", "up", "GPS_RAW_INT", "alt alt_ellipsoid"),
        *_c("altitude", "up", "GPS2_RAW", "alt alt_ellipsoid"),
        *_c("altitude", "up", "TERRAIN_REPORT", "current_height"),
        *_c("altitude", "up", "AHRS2", "altitude", **_AP),
        *_c("altitude", "up", "AHRS3", "altitude", **_AP),
        *_c("altitude", "up", "HIGHRES_IMU", "pressure_alt"),
        *_c("position", "north", "LOCAL_POSITION_NED", "x"),
        *_c("position", "north", "ODOMETRY", "x"),
        *_c("position", "north", "GLOBAL_POSITION_INT", "lat", M_PER_DEG),
        *_c("position", "north", "GPS_RAW_INT", "lat", M_PER_DEG),
        *_c("position", "north", "GPS2_RAW", "lat", M_PER_DEG),
        *_c("position", "north", "TERRAIN_REPORT", "lat", M_PER_DEG),
        *_c("position", "north", "AHRS2", "lat", M_PER_DEG, **_AP),
        *_c("position", "north", "AHRS3", "lat", M_PER_DEG, **_AP),
        *_c("position", "north", "SIMSTATE", "lat", M_PER_DEG, **_AP),
        *_c("position", "east", "LOCAL_POSITION_NED", "y"),
        *_c("position", "east", "ODOMETRY", "y"),
        *_c("position", "east", "GLOBAL_POSITION_INT", "lon", M_PER_DEG, lat_field="lat"),
        *_c("position", "east", "GPS_RAW_INT", "lon", M_PER_DEG, lat_field="lat"),
        *_c("position", "east", "GPS2_RAW", "lon", M_PER_DEG, lat_field="lat"),
        *_c("position", "east", "TERRAIN_REPORT", "lon", M_PER_DEG, lat_field="lat"),
        *_c("position", "east", "AHRS2", "lng", M_PER_DEG, lat_field="lat", **_AP),
        *_c("position", "east", "AHRS3", "lng", M_PER_DEG, lat_field="lat", **_AP),
        *_c("position", "east", "SIMSTATE", "lng", M_PER_DEG, lat_field="lat", **_AP),
    ]
)

# What still reveals a quantity and is not rewritten, with why (docs/profile.md lists these).
NOT_COVERED: dict[str, tuple[tuple[str, str], ...]] = {
    "rangefinder": (
        ("OBSTACLE_DISTANCE.distances", "proximity sectors; which sector a rangefinder feeds is the autopilot's setup"),
        ("ALTITUDE.bottom_clearance", "a fused clearance naming no sensor: it moves with the altitude quantity; "
         "PX4's (EKF2's distance to the ground) stays within 5 cm of its one downward rangefinder in SIH"),
        ("ALTITUDE.altitude_terrain", "PX4 puts the terrain's height there, altitude_local less the fused "
         "clearance, so the two give the clearance back"),
        ("OPTICAL_FLOW_RAD.distance", "PX4 fills it from the downward rangefinder when a flow sensor is fitted "
         "(SIH has none); not decoded by the attack engine"),
        ("RANGEFINDER.voltage", "an analog sensor's raw voltage, from which its distance can be worked out"),
    ),
    "altitude": (
        ("SCALED_PRESSURE*.press_abs, HIGHRES_IMU.abs_pressure", "barometric pressure, not metres"),
        ("GLOBAL_POSITION_INT_COV.alt, LOCAL_POSITION_NED_COV.z", "not decoded by the attack engine"),
        ("NAV_CONTROLLER_OUTPUT.alt_error", "a difference to the setpoint"),
    ),
    "position": (
        ("GLOBAL_POSITION_INT_COV.lat/lon, LOCAL_POSITION_NED_COV.x/y", "not decoded by the attack engine"),
        ("NAV_CONTROLLER_OUTPUT.wp_dist", "a distance to the setpoint"),
    ),
}
# Left alone on purpose: HOME_POSITION and GPS_GLOBAL_ORIGIN are reference points, not the vehicle.


def carriers_of(quantity: str, component: str | None = None) -> tuple[Carrier, ...]:
    """The carriers of ``quantity`` (one component, or all of them when ``component`` is None)."""
    return tuple(c for c in CARRIERS if c.quantity == quantity and component in (None, c.component))


def mapping_table() -> str:
    """The carrier table as Markdown, for docs/profile.md."""
    rows = ["| quantity | component | message | field | conversion | dialect |", "|---|---|---|---|---|---|"]
    for c in CARRIERS:
        if c.lat_field is not None:
            conv = f"east m = deg x {M_PER_DEG:.2f} x cos({c.lat_field})"
        elif c.factor == M_PER_DEG:
            conv = f"north m = deg x {M_PER_DEG:.2f}"
        elif c.factor == -1.0:
            conv = "minus (NED down)"
        else:
            conv = "same metres"
        which = {"id": "by its `id`", "primary": "the primary downward one", None: ""}[c.sensor]
        conv += f"; {which}" if which else ""
        rows.append(f"| {c.quantity} | {c.component} | {c.message} | `{c.field}` | {conv} | {c.dialect} |")
    rows += ["", "Not rewritten (a profile targeting the quantity is warned about these):", ""]
    for q, items in NOT_COVERED.items():
        rows += [f"- {q}: " + "; ".join(f"{name} ({why})" for name, why in items)]
    return "\n".join(rows) + "\n"

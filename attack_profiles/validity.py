"""Whether a frame's fields carry a reading at all, and the limits an attacked distance must stay in.

The engine asks here, per targeted frame, which of its fields carry no reading
(a range outside the sensor's limits or flagged invalid, a position before a
fix; the list is in :mod:`attack_profiles.engine`'s docstring) and what range
an attacked distance must stay in. ArduPilot's RANGEFINDER has no limits of its
own: it mirrors the primary downward DISTANCE_SENSOR (the lowest downward id a
vehicle has sent), whose limits and validity :func:`track_rangefinder` keeps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from attack_profiles.units import MESSAGES
from secuav_common.sensor_ids import ORIENTATION_DOWN, QUALITY_INVALID

# sysid -> DISTANCE_SENSOR id -> (min m, max m, invalid, downward)
Rangefinders = dict[int, dict[int, tuple[float, float, bool, bool]]]
Limits = tuple[str, float, float]  # (field, min m, max m)

DISTANCE_SENSOR_ID = MESSAGES["DISTANCE_SENSOR"].msgid
RANGEFINDER_ID = MESSAGES["RANGEFINDER"].msgid
# Messages whose lat/lon read 0/0 before the vehicle has a position (ArduPilot, PX4): no reading then.
_LATLON = {MESSAGES[n].msgid: (lat, lon) for n, lat, lon in (
    ("GLOBAL_POSITION_INT", "lat", "lon"), ("TERRAIN_REPORT", "lat", "lon"), ("AHRS2", "lat", "lng"),
    ("AHRS3", "lat", "lng"), ("SIMSTATE", "lat", "lng"))}  # fmt: skip
_NO_FIX = {  # what a missing position leaves without meaning, per message
    MESSAGES["GLOBAL_POSITION_INT"].msgid: frozenset({"lat", "lon", "alt"}),
    MESSAGES["TERRAIN_REPORT"].msgid: frozenset({"lat", "lon", "current_height"}),
    MESSAGES["AHRS2"].msgid: frozenset({"lat", "lng", "altitude"}),
    MESSAGES["AHRS3"].msgid: frozenset({"lat", "lng", "altitude"}),
    MESSAGES["SIMSTATE"].msgid: frozenset({"lat", "lng"}),
}
_GPS = frozenset({MESSAGES["GPS_RAW_INT"].msgid, MESSAGES["GPS2_RAW"].msgid})
_GPS_NO_FIX = frozenset({"lat", "lon", "alt", "alt_ellipsoid"})
_NO_ELLIPSOID = frozenset({"alt_ellipsoid"})
_ALTITUDE_ID = MESSAGES["ALTITUDE"].msgid
_ALTITUDE_UNKNOWN = {  # ALTITUDE: terrain below -1000 m and a negative clearance mean "unknown"
    (False, False): frozenset(),
    (True, False): frozenset({"altitude_terrain"}),
    (False, True): frozenset({"bottom_clearance"}),
    (True, True): frozenset({"altitude_terrain", "bottom_clearance"}),
}
NOTHING: frozenset[str] = frozenset()
RANGED = frozenset({DISTANCE_SENSOR_ID, RANGEFINDER_ID})  # messages whose range has the sensor's limits
_HIGHRES_IMU_ID = MESSAGES["HIGHRES_IMU"].msgid
_PRESSURE_ALT_BIT = 0x800  # HIGHRES_IMU_UPDATED_PRESSURE_ALT
_PRESSURE_ALT = frozenset(("pressure_alt",))
MAY_BE_UNREAD = RANGED | _GPS | set(_LATLON) | {_ALTITUDE_ID, _HIGHRES_IMU_ID}


def track_rangefinder(known_by_sysid: Rangefinders, sysid: int, fields: Mapping[str, Any]) -> None:
    """Note a DISTANCE_SENSOR's limits, validity and orientation (for the RANGEFINDER that mirrors it)."""
    sid = fields.get("id")
    lo, hi, q = fields.get("min_distance"), fields.get("max_distance"), fields.get("signal_quality", 0)
    if sid is None or lo is None or hi is None:
        return
    known = known_by_sysid.setdefault(sysid, {})
    if len(known) < 256 or sid in known:
        known[sid] = (lo * 0.01, hi * 0.01, q == QUALITY_INVALID, fields.get("orientation") == ORIENTATION_DOWN)


def primary(known_by_sysid: Rangefinders, sysid: int) -> int:
    """ArduPilot's RANGEFINDER carries its first downward rangefinder: the lowest downward id seen (0 before)."""
    known = known_by_sysid.get(sysid)
    if not known:
        return 0
    down = [sid for sid, info in known.items() if info[3]]
    return min(down) if down else 0


def limits(known_by_sysid: Rangefinders, msgid: int, fields: Mapping[str, Any], sysid: int, sid: int) -> Limits | None:
    """The sensor's own [min, max] (metres) for the range this frame carries, when known."""
    if msgid == DISTANCE_SENSOR_ID:
        lo, hi = fields.get("min_distance"), fields.get("max_distance")
        if lo is not None and hi is not None:
            return ("current_distance", lo * 0.01, hi * 0.01)
        return None
    info = known_by_sysid.get(sysid, {}).get(sid)  # RANGEFINDER: its primary DISTANCE_SENSOR's
    if info is None:
        return None
    # The primary flagged invalid: an empty range, nothing inside it is a reading.
    return ("distance", math.inf, -math.inf) if info[2] else ("distance", info[0], info[1])


_CURRENT_DISTANCE = frozenset(("current_distance",))
_DISTANCE = frozenset(("distance",))


def unread(msgid: int, fields: Mapping[str, Any], limits: Limits | None) -> frozenset[str]:
    """Fields of this frame that carry no reading: a range outside the sensor's limits or flagged
    invalid, a position before a fix (lat/lon 0/0, GPS fix_type below 2D), a GPS ellipsoid height
    of 0, ALTITUDE's "unknown" terrain height and clearance."""
    if msgid == DISTANCE_SENSOR_ID:
        cm = fields.get("current_distance")
        invalid = fields.get("signal_quality") == QUALITY_INVALID
        if cm is not None and (invalid or (limits is not None and not limits[1] <= cm * 0.01 <= limits[2])):
            return _CURRENT_DISTANCE
        return NOTHING
    if msgid == RANGEFINDER_ID:
        m = fields.get("distance")
        if m is None:
            return NOTHING
        if limits is None:  # no DISTANCE_SENSOR seen yet: ArduPilot reports 0 when it has no reading
            return _DISTANCE if not m > 0.0 else NOTHING
        return _DISTANCE if not limits[1] <= m <= limits[2] else NOTHING
    if msgid in _GPS:
        fix = fields.get("fix_type")
        if fix is not None and fix < 2:
            return _GPS_NO_FIX
        return _NO_ELLIPSOID if fields.get("alt_ellipsoid") == 0 else NOTHING  # 0: a receiver that gives none
    if msgid == _HIGHRES_IMU_ID:  # pressure_alt means something only when its bit says it was updated
        updated = fields.get("fields_updated")
        return _PRESSURE_ALT if updated is not None and not updated & _PRESSURE_ALT_BIT else NOTHING
    if msgid == _ALTITUDE_ID:
        terrain, clearance = fields.get("altitude_terrain"), fields.get("bottom_clearance")
        unknown = (terrain is not None and terrain < -1000.0, clearance is not None and clearance < 0.0)
        return _ALTITUDE_UNKNOWN[unknown]
    names = _LATLON.get(msgid)
    if names is not None and fields.get(names[0]) == 0 and fields.get(names[1]) == 0:
        return _NO_FIX[msgid]
    return NOTHING

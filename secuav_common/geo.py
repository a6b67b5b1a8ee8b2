"""Local NED <-> geodetic conversion around a home point.

Azimuthal equidistant projection on a sphere of the WGS84 equatorial radius,
the same choice PX4 makes for its local frame, so positions agree with what
QGroundControl plots for a PX4 vehicle to well under a centimetre over the few
hundred metres a scenario spans.
"""

from __future__ import annotations

import math

from secuav_common.scenario import Home

EARTH_RADIUS_M = 6_378_137.0


def ned_to_geodetic(home: Home, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """Return (lat_deg, lon_deg, alt_m AMSL) of a NED point."""
    lat0 = math.radians(home.lat_deg)
    lon0 = math.radians(home.lon_deg)
    x = north_m / EARTH_RADIUS_M
    y = east_m / EARTH_RADIUS_M
    c = math.hypot(x, y)
    if c < 1e-15:
        return home.lat_deg, home.lon_deg, home.alt_m - down_m
    sin_c, cos_c = math.sin(c), math.cos(c)
    lat = math.asin(cos_c * math.sin(lat0) + x * sin_c * math.cos(lat0) / c)
    lon = lon0 + math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
    return math.degrees(lat), math.degrees(lon), home.alt_m - down_m


def geodetic_to_ned(home: Home, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    """Return (north_m, east_m, down_m) of a geodetic point relative to home."""
    lat0 = math.radians(home.lat_deg)
    lat = math.radians(lat_deg)
    dlon = math.radians(lon_deg - home.lon_deg)
    cos_c = math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * math.cos(dlon)
    cos_c = max(-1.0, min(1.0, cos_c))
    c = math.acos(cos_c)
    k = 1.0 if c < 1e-15 else c / math.sin(c)
    north = k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * math.cos(dlon)) * EARTH_RADIUS_M
    east = k * math.cos(lat) * math.sin(dlon) * EARTH_RADIUS_M
    return north, east, home.alt_m - alt_m

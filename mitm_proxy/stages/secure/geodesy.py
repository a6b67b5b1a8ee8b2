"""From the estimate to the position messages: NED position of a result, and lat/lon/alt via the home.

The vehicle's HOME_POSITION ties the scenario's NED frame to lat/lon (the
scenario's home until one arrives); a garbled home (a garbage attack) keeps the
last good one. Values are held inside MAVLink's int32 range.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any

from mitm_proxy.stages.secure.layout import Layout
from mitm_proxy.stages.secure.worker import StepResult
from secuav_common.geo import ned_to_geodetic
from secuav_common.scenario import Home


def position_ned(layout: Layout, res: StepResult) -> tuple[float, float, float]:
    """The estimate's NED position; a 2-D model's down is the known height it stepped with (or its hold)."""
    pos = res.estimate.position_m
    if layout.position_dims == 3:
        return float(pos[0]), float(pos[1]), float(pos[2])
    known = res.job.known
    down = float(known) if isinstance(known, float) else float(getattr(layout.model, "vehicle_z_ned_m", math.nan))
    return float(pos[0]), float(pos[1]), down


def int32(v: float) -> int:
    """``v`` rounded and held inside MAVLink's int32 range."""
    return min(max(round(v), -(2**31)), 2**31 - 1)


class HomeTracker:
    """The home the position messages are computed from."""

    def __init__(self, home: Home) -> None:
        self.home = home

    def take(self, fields: dict[str, Any]) -> None:
        """A HOME_POSITION frame's fields (lat/lon in 1e-7 degrees, altitude in mm)."""
        lat, lon, alt = fields.get("latitude"), fields.get("longitude"), fields.get("altitude")
        if isinstance(lat, int) and isinstance(lon, int) and isinstance(alt, int) and (lat or lon):
            with contextlib.suppress(ValueError):  # out-of-range coordinates: keep the last good home
                self.home = Home(lat_deg=lat / 1e7, lon_deg=lon / 1e7, alt_m=alt / 1000.0)

    def global_int(self, pos_ned_m: tuple[float, float, float]) -> tuple[int, int, int, int]:
        """GLOBAL_POSITION_INT's ``lat``, ``lon`` (1e-7 deg), ``alt`` and ``relative_alt`` (mm) of a NED point."""
        north, east, down = pos_ned_m
        lat, lon, alt = ned_to_geodetic(self.home, north, east, down if math.isfinite(down) else 0.0)
        relative_mm = int32(-down * 1000.0) if math.isfinite(down) else 0
        return int32(lat * 1e7), int32(lon * 1e7), int32(alt * 1000.0), relative_mm

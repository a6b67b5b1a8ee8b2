"""Check an attacked stream against the stream that went in: every carrier of an attacked quantity
shifted by the profile's offset (no true copy left), everything else byte for byte.

The expectations are written out here from the MAVLink definitions (units, NED signs, what
"no reading" looks like), not taken from the engine, so the engine's own table is what is tested.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

M_PER_DEG = 6378137.0 * math.pi / 180.0
_MAV = dialect.MAVLink(None)
_MAV.robust_parsing = True


def parse(raw: bytes) -> Any:
    (msg,) = _MAV.parse_buffer(raw) or [None]
    assert msg is not None and msg.get_type() != "BAD_DATA", raw.hex()
    return msg


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


@dataclass
class Offsets:
    """The profile under test: +range_m on the rangefinders ``range_ids`` (None: all), +up_m, +north_m, +east_m."""

    range_m: float = 0.0
    range_ids: frozenset[int] | None = None
    up_m: float = 0.0
    north_m: float = 0.0
    east_m: float = 0.0

    def profile(self, name: str = "quantities") -> dict[str, Any]:
        rules: list[dict[str, Any]] = []
        if self.range_m:
            target: dict[str, Any] = {"quantity": "rangefinder"}
            if self.range_ids is not None:
                target["sensor_id"] = sorted(self.range_ids)
            rules.append({"target": target, "kind": "bias", "offset": self.range_m})
        if self.up_m:
            rules.append({"target": {"quantity": "altitude"}, "kind": "bias", "offset": self.up_m})
        for comp, value in (("north", self.north_m), ("east", self.east_m)):
            if value:
                rules.append({"target": {"quantity": "position", "field": comp}, "kind": "bias", "offset": value})
        return {"name": name, "rules": rules}


@dataclass
class Report:
    shifted: Counter[str] = field(default_factory=Counter)  # "MSG.field" -> frames carrying the lie
    kept: Counter[str] = field(default_factory=Counter)  # "MSG.field" -> no reading, left as it was
    exact: int = 0  # frames no rule concerns, byte for byte


def _close(got: float, want: float, tol: float) -> bool:
    return abs(got - want) <= tol


class Checker:
    def __init__(self, offsets: Offsets) -> None:
        self.o = offsets
        self.report = Report()
        self.limits: dict[int, tuple[int, int, bool]] = {}  # DISTANCE_SENSOR id -> (min cm, max cm, downward)

    # -- expectations per message -----------------------------------------------------------------

    def _moved(self, name: str, got: float, want: float, tol: float) -> None:
        assert _close(got, want, tol), f"{name}: got {got}, want {want}"
        self.report.shifted[name] += 1

    def _same(self, name: str, got: Any, was: Any) -> None:
        assert got == was or (got != got and was != was), f"{name}: changed {was} -> {got}"
        self.report.kept[name] += 1

    def _ds(self, a: Any, b: Any) -> set[str]:
        self.limits[a.id] = (a.min_distance, a.max_distance, a.orientation == 25)
        o = self.o
        if not o.range_m or (o.range_ids is not None and a.id not in o.range_ids):
            return set()
        if a.min_distance <= a.current_distance <= a.max_distance and a.signal_quality != 1:
            want = min(max(a.current_distance + round(o.range_m * 100), a.min_distance), a.max_distance)
            self._moved("DISTANCE_SENSOR.current_distance", b.current_distance, want, 1)
        else:
            self._same("DISTANCE_SENSOR.current_distance", b.current_distance, a.current_distance)
        return {"current_distance"}

    def _rangefinder(self, a: Any, b: Any) -> set[str]:
        o = self.o
        down = sorted(i for i, lim in self.limits.items() if lim[2])
        primary = down[0] if down else 0
        if not o.range_m or (o.range_ids is not None and primary not in o.range_ids):
            return set()
        lo, hi, _ = self.limits.get(primary, (0, 0, True))
        if (self.limits and lo * 0.01 <= a.distance <= hi * 0.01) or (not self.limits and a.distance > 0):
            want = a.distance + o.range_m
            if self.limits:
                want = min(max(want, lo * 0.01), hi * 0.01)
            self._moved("RANGEFINDER.distance", b.distance, f32(want), 1e-5 * max(1.0, abs(want)))
        else:
            self._same("RANGEFINDER.distance", b.distance, a.distance)
        return {"distance"}

    def _latlon(self, name: str, a: Any, b: Any, lat: str, lon: str, fix: bool) -> set[str]:
        o = self.o
        if not (o.north_m or o.east_m):
            return set()
        for f in (lat, lon):
            if not fix:
                self._same(f"{name}.{f}", getattr(b, f), getattr(a, f))
        if fix:
            lat_deg = getattr(a, lat) * 1e-7
            self._moved(f"{name}.{lat}", getattr(b, lat), getattr(a, lat) + o.north_m / M_PER_DEG * 1e7, 1.0)
            east = o.east_m / (M_PER_DEG * math.cos(math.radians(lat_deg))) * 1e7
            self._moved(f"{name}.{lon}", getattr(b, lon), getattr(a, lon) + east, 1.0)
        return {lat, lon}

    def _heights(self, name: str, a: Any, b: Any, fields: dict[str, float], fix: bool = True) -> set[str]:
        """``fields``: name -> wire units per metre up (negative for NED z)."""
        if not self.o.up_m:
            return set()
        for f, per_m in fields.items():
            was, got = getattr(a, f), getattr(b, f)
            if not fix:
                self._same(f"{name}.{f}", got, was)
            elif isinstance(was, float):
                want = f32(was + per_m * self.o.up_m)
                self._moved(f"{name}.{f}", got, want, 1e-6 * max(1.0, abs(want)))
            else:
                self._moved(f"{name}.{f}", got, was + per_m * self.o.up_m, 1.0)
        return set(fields)

    def _local(self, name: str, a: Any, b: Any) -> set[str]:
        o = self.o
        out = set()
        for f, d in (("x", o.north_m), ("y", o.east_m)):
            if d:
                want = f32(getattr(a, f) + d)
                self._moved(f"{name}.{f}", getattr(b, f), want, 1e-6 * max(1.0, abs(want)))
                out.add(f)
        return out | self._heights(name, a, b, {"z": -1.0})

    def expected(self, a: Any, b: Any) -> set[str] | None:
        """Check the carriers of ``a`` (in) in ``b`` (out); the fields checked, or None: not a carrier."""
        t = a.get_type()
        if t == "DISTANCE_SENSOR":
            return self._ds(a, b)
        if t == "RANGEFINDER":
            return self._rangefinder(a, b)
        if t == "GLOBAL_POSITION_INT":
            fix = not (a.lat == 0 and a.lon == 0)
            return (self._latlon(t, a, b, "lat", "lon", fix) | self._heights(t, a, b, {"alt": 1000.0}, fix)
                    | self._heights(t, a, b, {"relative_alt": 1000.0}))  # fmt: skip
        if t in ("GPS_RAW_INT", "GPS2_RAW"):  # alt_ellipsoid 0: the receiver gives none
            fix = a.fix_type >= 2
            return (self._latlon(t, a, b, "lat", "lon", fix) | self._heights(t, a, b, {"alt": 1000.0}, fix)
                    | self._heights(t, a, b, {"alt_ellipsoid": 1000.0}, fix and a.alt_ellipsoid != 0))  # fmt: skip
        if t in ("AHRS2", "AHRS3"):
            fix = not (a.lat == 0 and a.lng == 0)
            return self._latlon(t, a, b, "lat", "lng", fix) | self._heights(t, a, b, {"altitude": 1.0}, fix)
        if t == "SIMSTATE":
            return self._latlon(t, a, b, "lat", "lng", not (a.lat == 0 and a.lng == 0))
        if t == "TERRAIN_REPORT":
            fix = not (a.lat == 0 and a.lon == 0)
            return self._latlon(t, a, b, "lat", "lon", fix) | self._heights(t, a, b, {"current_height": 1.0}, fix)
        if t in ("LOCAL_POSITION_NED", "ODOMETRY"):
            return self._local(t, a, b)
        if t == "HIGHRES_IMU":
            return self._heights(t, a, b, {"pressure_alt": 1.0}, bool(a.fields_updated & 0x800))
        if t == "VFR_HUD":
            return self._heights(t, a, b, {"alt": 1.0})
        if t == "ALTITUDE":
            names = ("altitude_monotonic", "altitude_amsl", "altitude_local", "altitude_relative")
            return (self._heights(t, a, b, dict.fromkeys(names, 1.0))
                    | self._heights(t, a, b, {"altitude_terrain": 1.0}, a.altitude_terrain >= -1000.0)
                    | self._heights(t, a, b, {"bottom_clearance": 1.0}, a.bottom_clearance >= 0.0))  # fmt: skip
        return None

    def check(self, frames_in: Sequence[bytes], frames_out: Sequence[bytes]) -> Report:
        assert len(frames_in) == len(frames_out), (len(frames_in), len(frames_out))
        for raw_in, raw_out in zip(frames_in, frames_out, strict=True):
            a = parse(raw_in)
            checked = self.expected(a, parse(raw_out)) if raw_in != raw_out or _carrier(a) else None
            if not checked:
                assert raw_out == raw_in, f"{a.get_type()} changed although nothing targets it"
                self.report.exact += 1
                continue
            b = parse(raw_out)
            assert b.get_header().seq == a.get_header().seq and b.get_srcSystem() == a.get_srcSystem()
            for name in a.get_fieldnames():  # every other field as it came
                if name not in checked:
                    self._same_quiet(f"{a.get_type()}.{name}", getattr(b, name), getattr(a, name))
        return self.report

    @staticmethod
    def _same_quiet(name: str, got: Any, was: Any) -> None:
        same = got == was or (isinstance(was, float) and was != was and got != got)
        if isinstance(was, list):
            same = all(x == y or (x != x and y != y) for x, y in zip(got, was, strict=True))
        assert same, f"{name}: changed {was} -> {got}"


_CARRIERS = {"DISTANCE_SENSOR", "RANGEFINDER", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW", "AHRS2", "AHRS3",
             "SIMSTATE", "TERRAIN_REPORT", "LOCAL_POSITION_NED", "ODOMETRY", "VFR_HUD", "ALTITUDE",
             "HIGHRES_IMU"}  # fmt: skip


def _carrier(msg: Any) -> bool:
    return msg.get_type() in _CARRIERS

"""The vehicle's estimator taking a companion's readings over MAVLink (scenario ``external``).

The vehicle's own estimate (:class:`flightsim.sensors.StateEstimator`: GPS quality position, IMU quality
velocity and attitude) stays the base. On every control tick :meth:`ExternalFusion.fuse` replaces parts of
its position with what the companion said, as PX4's EKF2 does with ``EKF2_EV_CTRL`` (vision) and
``EKF2_HGT_REF`` = range, or ArduPilot's EKF3 with ``EK3_SRC1_POSXY 6`` and ``EK3_SRC1_POSZ 2``:

- a position source (VISION_POSITION_ESTIMATE / ODOMETRY, or a least-squares fix of UWB anchor ranges):
  the whole position follows it;
- a rangefinder measuring a plane (the ground, a wall): the position along that plane's normal follows
  the perpendicular distance the beam implies, ``h = d * -(u . n)`` for a beam of unit direction ``u``
  (the mount rotated by the estimated attitude) and the plane's normal ``n`` (toward the free side).

Each source is a complementary filter: between readings the fused value moves with the estimated
velocity, and each reading pulls it by ``GAIN`` of the innovation (a steady-state Kalman gain: at 20 Hz a
time constant near 0.2 s, which averages a 2 cm laser's noise down without lagging a manoeuvre). So a
reading that lies by a bias moves the estimate by that bias within a second, and the position controller
moves the vehicle by it: the attack reaches the airframe.

A source whose last valid reading is older than ``timeout_s`` (sim time) is dropped: its part of the
estimate goes back to the base, and the vehicle says so (STATUSTEXT WARNING); when readings return it is
taken again (INFO), starting from the reading itself rather than from a stale filter state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from flightsim.api import ExternalPosition, ExternalRange, RangeReading, State
from flightsim.control.rotation import Vec3, rotate
from flightsim.world import GROUND, Plane
from secuav_common import scenario as sc
from secuav_common.sensor_ids import (
    MOUNT_BODY,
    ORIENTATION,
    ORIENTATION_CUSTOM,
    SENSOR_TYPE,
    SENSOR_TYPE_UNKNOWN,
    anchor_sensor_id,
)

GAIN = 0.2
UWB_MIN_RANGES = 4  # a 3-D fix; fewer fresh ranges hold the last position source state
UWB_ITERATIONS = 4
INFO, WARNING = 6, 4  # MAV_SEVERITY


@dataclass(slots=True)
class _Source:
    """One external source's freshness and filter state."""

    name: str
    last_t_s: float = -math.inf
    pending: float | Vec3 | None = None  # a reading not yet fused
    value: float | Vec3 | None = None  # the filter's state; None until first used or after a drop-out
    in_use: bool = False


@dataclass(slots=True)
class FusionStats:
    taken: int = 0
    ignored: int = 0  # wrong source, undeclared id, wrong orientation
    invalid: int = 0  # out of the sensor's range: "no target"
    dropouts: int = 0


class ExternalFusion:
    """Fuses one vehicle's external readings into its estimate; see the module doc."""

    def __init__(
        self,
        cfg: sc.ExternalInputs,
        sysid: int,
        planes: dict[str, Plane],
        anchors: dict[int, Vec3],
    ) -> None:
        self.cfg = cfg
        self.source_sysid = cfg.source_sysid if cfg.source_sysid is not None else sysid
        self.source_compids = frozenset(cfg.source_compids)
        self.rangefinders = {r.id: r for r in cfg.rangefinders}
        self._planes = {r.id: planes.get(r.surface, GROUND) for r in cfg.rangefinders}
        self._ranges = {r.id: _Source(f"rangefinder {r.id}") for r in cfg.rangefinders}
        uwb_ids = list(anchors) if cfg.uwb is None or cfg.uwb.anchors == "all" else list(cfg.uwb.anchors)
        self.anchors = {anchor_sensor_id(k): anchors[k] for k in uwb_ids} if cfg.uwb is not None else {}
        self._uwb: dict[int, tuple[float, float]] = {}  # sensor id -> (t_s, range m)
        self._uwb_new = False
        self._position = _Source("vision" if cfg.vision is not None else "UWB position")
        self.stats = FusionStats()
        self.status: list[tuple[int, str]] = []
        self.reports: list[RangeReading] = []  # what the vehicle re-reports as its own DISTANCE_SENSOR

    # -- in ---------------------------------------------------------------------------------
    def _from_companion(self, src_sysid: int, src_compid: int) -> bool:
        return src_sysid == self.source_sysid and src_compid in self.source_compids

    def take_range(self, r: ExternalRange, t_s: float) -> bool:
        """A DISTANCE_SENSOR at sim time ``t_s``: True if it was one the vehicle expects."""
        if not self._from_companion(r.src_sysid, r.src_compid):
            self.stats.ignored += 1
            return False
        rf = self.rangefinders.get(r.sensor_id)
        if rf is not None:
            if r.orientation != ORIENTATION[rf.orientation]:
                self.stats.ignored += 1
                return False
            valid = math.isfinite(r.distance_m) and rf.min_m <= r.distance_m <= rf.max_m
            value = r.distance_m if valid else math.nan
            kind, facing = SENSOR_TYPE[rf.type], ORIENTATION[rf.orientation]
            self.reports.append(RangeReading(rf.id, t_s, value, rf.min_m, rf.max_m, kind, facing, rf.noise_std_m))
            if not valid:
                self.stats.invalid += 1
                return True
            src = self._ranges[rf.id]
            src.pending, src.last_t_s = r.distance_m, t_s
            self.stats.taken += 1
            return True
        uwb = self.cfg.uwb
        if uwb is not None and r.sensor_id in self.anchors and r.orientation == ORIENTATION_CUSTOM:
            valid = math.isfinite(r.distance_m) and 0.0 < r.distance_m <= uwb.max_m
            self.reports.append(RangeReading(r.sensor_id, t_s, r.distance_m if valid else math.nan, 0.0, uwb.max_m,
                                             SENSOR_TYPE_UNKNOWN, ORIENTATION_CUSTOM, uwb.noise_std_m))  # fmt: skip
            if not valid:
                self.stats.invalid += 1
                return True
            self._uwb[r.sensor_id] = (t_s, r.distance_m)
            self._uwb_new = True
            self.stats.taken += 1
            return True
        self.stats.ignored += 1
        return False

    def take_position(self, fix: ExternalPosition, t_s: float) -> bool:
        if self.cfg.vision is None or not self._from_companion(fix.src_sysid, fix.src_compid):
            self.stats.ignored += 1
            return False
        if not all(math.isfinite(c) for c in fix.pos_ned_m):
            self.stats.invalid += 1
            return True
        self._position.pending, self._position.last_t_s = fix.pos_ned_m, t_s
        self.stats.taken += 1
        return True

    # -- the estimate -------------------------------------------------------------------------
    def fuse(self, base: State, dt_s: float) -> State:
        """``base`` with the parts the external sources give replaced; call once per control tick."""
        t = base.t_s
        vel = base.vel_ned_m_s
        if self.anchors:
            self._uwb_fix(base, t)
        pos = self._fuse_position(base, t, dt_s)
        for sid, src in self._ranges.items():
            plane = self._planes[sid]
            n = plane.normal
            if not self._fresh(src, t):
                continue
            h_rate = vel[0] * n[0] + vel[1] * n[1] + vel[2] * n[2]
            reading = src.pending
            h_meas = None
            if isinstance(reading, float):
                u = rotate(base.quat, MOUNT_BODY[self.rangefinders[sid].orientation])
                cos_incidence = -(u[0] * n[0] + u[1] * n[1] + u[2] * n[2])
                h_meas = reading * cos_incidence if cos_incidence > 0.1 else None  # a grazing beam says little
            src.pending = None
            h = self._filter_scalar(src, h_rate * dt_s, h_meas)
            if h is None:
                continue
            off = h - plane.signed_distance(pos)
            pos = (pos[0] + off * n[0], pos[1] + off * n[1], pos[2] + off * n[2])
        return replace(base, pos_ned_m=pos)

    def _fuse_position(self, base: State, t: float, dt_s: float) -> Vec3:
        src = self._position
        if not self._fresh(src, t):
            return base.pos_ned_m
        fix = src.pending
        src.pending = None
        v = base.vel_ned_m_s
        if src.value is None:
            if fix is None:
                return base.pos_ned_m
            src.value = fix  # (re)start from the reading itself
        else:
            p = src.value
            assert isinstance(p, tuple)
            p = (p[0] + v[0] * dt_s, p[1] + v[1] * dt_s, p[2] + v[2] * dt_s)
            if isinstance(fix, tuple):
                p = tuple(pi + GAIN * (fi - pi) for pi, fi in zip(p, fix, strict=True))  # type: ignore[assignment]
            src.value = p
        out = src.value
        assert isinstance(out, tuple)
        return out  # type: ignore[return-value]

    def _filter_scalar(self, src: _Source, step: float, meas: float | None) -> float | None:
        if src.value is None:
            if meas is None:
                return None
            src.value = meas
            return meas
        assert isinstance(src.value, float)
        h = src.value + step
        if meas is not None:
            h += GAIN * (meas - h)
        src.value = h
        return h

    def _fresh(self, src: _Source, t: float) -> bool:
        """Is ``src`` usable at ``t``? Says so when it starts or stops being used."""
        fresh = t - src.last_t_s <= self.cfg.timeout_s
        if fresh and not src.in_use:
            src.in_use = True
            self.status.append((INFO, f"External {src.name} in use"))
        elif not fresh and src.in_use:
            src.in_use, src.value, src.pending = False, None, None
            self.stats.dropouts += 1
            self.status.append((WARNING, f"External {src.name} lost for {self.cfg.timeout_s:g} s: using own estimate"))
        return fresh

    def _uwb_fix(self, base: State, t: float) -> None:
        """A least-squares fix from the fresh anchor ranges, when a new range arrived since the last one."""
        if not self._uwb_new:
            return
        fresh = [(self.anchors[sid], r) for sid, (ts, r) in self._uwb.items() if t - ts <= self.cfg.timeout_s]
        if len(fresh) < UWB_MIN_RANGES:
            return
        self._uwb_new = False
        start = self._position.value if isinstance(self._position.value, tuple) else base.pos_ned_m
        fix = multilaterate(start, fresh)
        if fix is not None:
            self._position.pending, self._position.last_t_s = fix, t

    def sources_in_use(self) -> list[str]:
        """The sources the estimate takes now (``rangefinder 0``, ``vision``, ``UWB position``)."""
        return [s.name for s in (*self._ranges.values(), self._position) if s.in_use]

    def pop_status(self) -> list[tuple[int, str]]:
        out, self.status = self.status, []
        return out

    def pop_reports(self) -> list[RangeReading]:
        out, self.reports = self.reports, []
        return out


def multilaterate(start: Vec3, ranges: list[tuple[Vec3, float]]) -> Vec3 | None:
    """Gauss-Newton least squares of ``|p - a_i| = r_i`` from ``start``; None when the geometry is singular."""
    a = np.array([anchor for anchor, _ in ranges], dtype=float)
    r = np.array([dist for _, dist in ranges], dtype=float)
    p = np.array(start, dtype=float)
    for _ in range(UWB_ITERATIONS):
        diff = p - a
        pred = np.linalg.norm(diff, axis=1)
        if np.any(pred < 1e-6):
            p = p + 0.01  # on an anchor: the gradient is undefined, step off it
            continue
        jac = diff / pred[:, None]
        step, _res, rank, _sv = np.linalg.lstsq(jac, r - pred, rcond=None)
        if rank < 3:
            return None
        p = p + step
    if not np.all(np.isfinite(p)):
        return None
    return float(p[0]), float(p[1]), float(p[2])

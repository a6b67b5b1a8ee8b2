"""Collecting the group's readings between two estimator steps, and deciding when a step is due.

A reading is the group sensor's DISTANCE_SENSOR value, NaN when the sensor
reports "no target": ``signal_quality`` 0 with ``current_distance`` outside the
frame's own ``min_distance``..``max_distance`` (flightsim and PX4 send max + 1,
ArduPilot 0 on the ground). ``signal_quality`` 0 alone is MAVLink's "unknown",
which ArduPilot sends on every reading of a sensor that does not grade itself
(its SITL rangefinders do not); a reading out of range with a quality (an
attack's, say) stays a reading for the estimator to judge. A set is due when every sensor has
reported since the last step (a sensor silent for longer than ``max_age_s`` is
not waited for), ``max_wait_s`` after the first one did (so a dropped sensor
cannot stall the estimator), or at ``rate_hz`` when configured. When the
group (re)starts, the first set after no step for ``max_age_s`` (the first of
all, or after a stall), every sensor is waited for, up to ``max_wait_s``: a
vehicle that sends its group in one burst (ArduPilot: ids 0, 1, 2 together, 10
times a second) then has each set hold one burst, where stepping on the
burst's first frame alone would pair every later burst's first reading with
the others' of the burst before, 0.1 s older: in a 1 m/s climb a 0.1 m
disagreement, which the estimators take for an attack on the first sensor. The
same holds inside a burst when the group's sensors run at different rates
(flightsim's wall group: four at 20 Hz, the sonar at 10 Hz, sent in id order):
the set is complete when the sonar, id 2, arrives, while ids 3 and 4 still hold
the previous burst's readings, 50 ms older (0.05-0.1 m apart on the approach,
flagged as attacks). So a complete set also waits, up to ``max_wait_s``, for a
sensor whose next reading is due at the newest reading's time, by the vehicle's
clock (``time_boot_ms``; each sensor's period is the spacing of its last two
stamps). A reading older than ``max_age_s`` goes into the step as NaN.

Each reading's time is when the vehicle took it, not when it arrived: its ``time_boot_ms`` mapped onto the proxy's
clock per sender (:mod:`mitm_proxy.stages.secure.stamps`; ``reading_time: arrival`` keeps the arrival). That time
is what the asynchronous estimators get with the reading and what its age is judged by; when a set is due is
still a matter of arrivals (a reading is news when it comes).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

from mitm_proxy.stages.secure import tilt
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.layout import Layout
from mitm_proxy.stages.secure.stamps import Source, StampClock
from mitm_proxy.stages.secure.worker import Job
from secuav_common.sensor_ids import QUALITY_UNKNOWN

NO_TARGET_QUALITY = QUALITY_UNKNOWN  # sent with "no target" too
HEIGHT_MAX_AGE_S = 2.0  # a known height older than this is not used (the model's hold height is)
VELOCITY_MAX_AGE_S = 0.5  # an older velocity is not the motion input (the filter then predicts without it)
ATTITUDE_MAX_AGE_S = 0.25  # an older attitude does not project the readings (they go in as measured)
DUE_SLACK = 0.3  # of a sensor's period: how far past the newest stamp its next reading may be and still be awaited

Due = Literal["complete", "timed_out", "rate"]


def no_target(fields: dict[str, Any]) -> bool:
    """A DISTANCE_SENSOR frame that says "nothing in range": quality unknown and the distance outside its limits."""
    if fields.get("signal_quality", 100) != NO_TARGET_QUALITY:
        return False
    cm = fields.get("current_distance", 0)
    return not fields.get("min_distance", 0) <= cm <= fields.get("max_distance", 65535)


class Readings:
    """The reading vector of one layout and the clock of its sets (proxy monotonic time)."""

    def __init__(self, layout: Layout, clock: StampClock | None = None) -> None:
        p = layout.p
        self.clock = clock if clock is not None else StampClock()
        self.z = np.full(p, np.nan)
        self.rx = np.full(p, -math.inf)  # proxy time of each sensor's latest reading's arrival
        self.taken_s = np.full(p, -math.inf)  # proxy time it was taken at (its stamp mapped: stamps.py)
        self.fresh = np.zeros(p, dtype=bool)  # reported since the last step
        self.stamp_ms = np.full(p, np.nan)  # the vehicle's time_boot_ms of each sensor's latest reading
        self.period_ms = np.full(p, np.nan)  # the spacing of its last two readings' stamps
        self.pending_since: float | None = None
        self.last_submit_s = -math.inf
        self.sim_t_s: float | None = None  # the vehicle's clock of the newest reading, to join with truth
        self.height_m: float | None = None  # known NED z (2-D anchors)
        self.height_rx = -math.inf
        self.velocity: np.ndarray | None = None  # the vehicle's own NED velocity: the filters' motion input
        self.velocity_rx = -math.inf
        self.geometry = layout.tilt  # the wall group's beams and normal, when ATTITUDE projects its readings
        self.factors: np.ndarray | None = None  # each reading's projection at the latest ATTITUDE (tilt.py)
        self.factors_rx = -math.inf

    def take_range(self, layout: Layout, fields: dict[str, Any], now_s: float, source: Source = (0, 0)) -> bool:
        """A DISTANCE_SENSOR frame's fields from ``source`` (sysid, compid); True when it was one of the group's
        readings."""
        sid = fields.get("id")
        distance_m = fields.get("current_distance", 0) / 100.0
        valid = not no_target(fields)
        if sid == layout.height_sensor_id and valid:
            self.take_height(-distance_m, now_s)
        i = layout.index_of.get(sid) if isinstance(sid, int) else None
        if i is None:
            return False
        self.z[i] = distance_m if valid else math.nan
        self.rx[i] = now_s
        self.fresh[i] = True
        boot_ms = fields.get("time_boot_ms")
        self.taken_s[i] = self.clock.time_of(source, boot_ms, now_s)
        if isinstance(boot_ms, int):
            self.sim_t_s = boot_ms / 1000.0 if self.sim_t_s is None else max(self.sim_t_s, boot_ms / 1000.0)
            if boot_ms > self.stamp_ms[i]:
                self.period_ms[i] = boot_ms - self.stamp_ms[i]
            elif boot_ms < self.stamp_ms[i]:  # the vehicle rebooted: its periods start again
                self.period_ms[:] = np.nan
            self.stamp_ms[i] = boot_ms
        if self.pending_since is None:
            self.pending_since = now_s
        return True

    def take_height(self, z_ned_m: float, now_s: float) -> None:
        self.height_m, self.height_rx = z_ned_m, now_s

    def take_velocity(self, fields: dict[str, Any], now_s: float) -> None:
        """LOCAL_POSITION_NED's vx, vy, vz (a filter built with ``velocity_std_mps`` reads them)."""
        vel = [fields.get(k) for k in ("vx", "vy", "vz")]
        if all(isinstance(v, float) and math.isfinite(v) for v in vel):
            self.velocity, self.velocity_rx = np.array(vel, dtype=float), now_s

    def take_attitude(self, fields: dict[str, Any], now_s: float) -> None:
        """ATTITUDE's angles, turned into the readings' projection factors once per frame (not per reading)."""
        angles = tilt.attitude(fields)
        if angles is not None and self.geometry is not None:
            self.factors, self.factors_rx = self.geometry.factors(*angles), now_s

    def tilt_factors(self, now_s: float) -> np.ndarray | None:
        """Each reading's projection on the wall's normal at the latest attitude; None without a fresh one."""
        return self.factors if now_s - self.factors_rx <= ATTITUDE_MAX_AGE_S else None

    def due(self, cfg: SecureConfig, now_s: float) -> Due | None:
        """Why a step is due now, or None."""
        if self.pending_since is None:
            return None
        if cfg.rate_hz is not None:
            return "rate" if now_s - self.last_submit_s >= 1.0 / cfg.rate_hz - 1e-6 else None  # no float loss
        restarting = self.pending_since - self.last_submit_s > cfg.max_age_s  # the burst is still arriving
        if restarting and now_s - self.pending_since < cfg.max_wait_s:
            silent = np.zeros_like(self.fresh)
        else:
            silent = now_s - self.rx > cfg.max_age_s
        if np.all(self.fresh | silent) and not self._next_in_burst(silent):  # a silent sensor is not waited for
            return "complete"
        return "timed_out" if now_s - self.pending_since >= cfg.max_wait_s else None

    def _next_in_burst(self, silent: np.ndarray) -> bool:
        """Whether a sensor's next reading is due at the newest reading's stamp: it is on its way in this burst."""
        newest = np.nanmax(self.stamp_ms, initial=-np.inf)
        with np.errstate(invalid="ignore"):
            due = self.stamp_ms + self.period_ms * (1.0 - DUE_SLACK) <= newest
        return bool(np.any(due & ~silent))

    def job(self, cfg: SecureConfig, layout: Layout, now_s: float) -> Job:
        """The set to step now (stale readings as NaN); the next set starts empty."""
        z = np.where(now_s - self.taken_s <= cfg.max_age_s, self.z, np.nan)
        factors = self.tilt_factors(now_s)
        if factors is not None:
            z = z * factors  # along the wall's normal; a beam past 60 degrees off it is missing (NaN)
        known: float | None = None
        if layout.position_dims == 2:
            fresh_height = self.height_m is not None and now_s - self.height_rx <= HEIGHT_MAX_AGE_S
            known = self.height_m if fresh_height else None  # None: the model's hold height
        self.fresh[:] = False
        self.pending_since = None
        self.last_submit_s = now_s
        velocity = self.velocity if now_s - self.velocity_rx <= VELOCITY_MAX_AGE_S else None
        times = np.where(np.isfinite(z), self.taken_s, np.nan)  # when each was taken, for asynchronous processing
        return Job(t_s=now_s, z=z, known=known, sim_t_s=self.sim_t_s, rx_s=now_s, velocity=velocity, tilt=factors,
                   times=times)  # fmt: skip

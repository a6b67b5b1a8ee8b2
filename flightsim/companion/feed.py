"""What a companion computer sends an autopilot, from a true state: the sans-I/O part of ``secuav-feed``.

:class:`FeedBuilder` turns each true state it is given into the MAVLink messages that fall due, each
sensor on its own clock, with flightsim's noise models (the ones the simulator's own sensors use, seeded
the same way, so a seed gives the same feed):

- ``rangefinders``: DISTANCE_SENSOR per rangefinder of the scenario's ``external`` block (else of the
  vehicle's ``sensors``, for an autopilot such as ArduPilot SITL told they come over MAVLink), ray-cast
  against its walls and the ground (:class:`flightsim.sensors.RangefinderModel`);
- ``uwb``: DISTANCE_SENSOR id 10+k per anchor of ``external.uwb`` (else ``sensors.uwb``)
  (:class:`flightsim.sensors.UwbModel`, its ``noise:`` block included);
- ``vision``: VISION_POSITION_ESTIMATE, ``odometry``: ODOMETRY (local NED), the true position plus
  N(0, ``external.vision.noise_std_m``) per axis;
- ``gps_input``: GPS_INPUT (ArduPilot ``GPS_TYPE 14``), ``hil_gps``: HIL_GPS (PX4), from
  :class:`flightsim.sensors.GpsModel` with the vehicle's ``sensors.gps`` noise.

Messages are stamped with the state's time (``time_boot_ms``, ``time_usec``), so a reading and the truth
it came from can be joined later.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import GpsFix, RangeReading, State
from flightsim.noise import stream
from flightsim.sensors import GpsModel, PositionError, RangefinderModel, UwbModel, _Clock
from flightsim.world import World
from secuav_common import scenario as sc

Message = mavlink.MAVLink_message
SENSORS = ("rangefinders", "uwb", "vision", "odometry", "gps_input", "hil_gps")
FEED_COMPID = sc.COMPANION_COMPIDS[0]  # MAV_COMP_ID_PERIPHERAL
# GPS time (s since the GPS epoch, 1980-01-06, 18 leap seconds ahead of UTC) of 2026-01-01 00:00 UTC: sim
# time 0 of every GPS feed, so a given flight always carries the same week and time of week.
GPS_TIME_AT_SIM_ZERO_S = 1767225600 - 315964800 + 18
WEEK_MS = 7 * 24 * 3600 * 1000
NO_COVARIANCE = [math.nan] * 21  # ODOMETRY: "unknown" as MAVLink spells it


@dataclass(slots=True)
class FeedCounts:
    states: int = 0
    sent: dict[str, int] = field(default_factory=dict)  # message name -> count


def default_sensors(vehicle: sc.Vehicle) -> list[str]:
    """What the scenario's ``external`` block declares (GPS feeds only on request: flightsim does not fuse them)."""
    ext = vehicle.external
    if ext is None:
        return []
    out = ["rangefinders"] if ext.rangefinders else []
    if ext.uwb is not None:
        out.append("uwb")
    if ext.vision is not None:
        out.append("vision" if ext.vision.message == "vision_position_estimate" else "odometry")
    return out


class FeedBuilder:
    """``messages(state)`` -> the messages due at ``state.t_s``; see the module doc."""

    def __init__(
        self,
        scenario: sc.Scenario,
        sysid: int,
        sensors: Iterable[str],
        mav: mavlink.MAVLink,
        seed: int | None = None,
        rate_hz: float | None = None,
    ) -> None:
        self.sensors = list(dict.fromkeys(sensors))
        unknown = [s for s in self.sensors if s not in SENSORS]
        if unknown:
            raise ValueError(f"sensor {unknown[0]!r}: expected one of {', '.join(SENSORS)}")
        vehicle = scenario.vehicle(sysid)
        ext = vehicle.external or sc.ExternalInputs()
        self.mav = mav
        self.home = scenario.world.home
        self.counts = FeedCounts()
        seed = scenario.seed if seed is None else seed
        # A stream name apart from the simulator's own sensors': the feed's noise is its own draw.
        rng = lambda name: stream(seed, sysid, f"feed/{name}")  # noqa: E731
        world = World(scenario.world)
        self.rangefinders: list[RangefinderModel] = []
        if "rangefinders" in self.sensors:
            # A SITL's MAVLink rangefinders are the scenario's own (ardupilot_height) when it has no external block.
            mounted = ext.rangefinders or vehicle.sensors.rangefinders
            if not mounted:
                raise ValueError(f"vehicle {sysid}: no rangefinders to feed (external or sensors)")
            for r in mounted:
                cfg = r if rate_hz is None else r.model_copy(update={"rate_hz": rate_hz})
                self.rangefinders.append(RangefinderModel(cfg, world, rng(f"rangefinder{r.id}")))
        self.uwb: UwbModel | None = None
        if "uwb" in self.sensors:
            uwb = vehicle.uwb_ranging
            if uwb is None:
                raise ValueError(f"vehicle {sysid}: the scenario declares no external.uwb (nor sensors.uwb) to feed")
            if rate_hz is not None:
                uwb = uwb.model_copy(update={"rate_hz": rate_hz})
            self.uwb = UwbModel(uwb, scenario.anchor_positions(uwb.anchors), rng("uwb"))
        vision = ext.vision or sc.ExternalVision()
        self.vision_std_m = vision.noise_std_m
        self.vision_dropout = vision.dropout_prob
        vision_rate = rate_hz or vision.rate_hz
        self._vision_clock = {k: _Clock(vision_rate) for k in ("vision", "odometry") if k in self.sensors}
        self._vision_rng = rng("vision")
        gps_cfg = vehicle.sensors.gps.model_copy(update={"enabled": True, "rate_hz": rate_hz or
                                                         vehicle.sensors.gps.rate_hz})  # fmt: skip
        self.gps: GpsModel | None = None
        if "gps_input" in self.sensors or "hil_gps" in self.sensors:
            self.gps = GpsModel(gps_cfg, self.home, PositionError(gps_cfg, rng("gps-error")), rng("gps"))

    def messages(self, truth: State) -> list[Message]:
        """The messages due at ``truth.t_s`` (the sensors' clocks start at the first state given)."""
        self.counts.states += 1
        out: list[Message] = []
        for rf in self.rangefinders:
            r = rf.sample(truth)
            if r is not None:
                out.append(self.distance_sensor(r))
        if self.uwb is not None:
            out.extend(self.distance_sensor(r) for r in self.uwb.sample(truth))
        for kind, clock in self._vision_clock.items():
            if clock.due(truth.t_s):
                msg = self.vision(truth, kind)
                if msg is not None:
                    out.append(msg)
        if self.gps is not None:
            fix = self.gps.sample(truth)
            if fix is not None:
                if "gps_input" in self.sensors:
                    out.append(self.gps_input(fix))
                if "hil_gps" in self.sensors:
                    out.append(self.hil_gps(fix))
        for msg in out:
            name = msg.get_type()
            self.counts.sent[name] = self.counts.sent.get(name, 0) + 1
        return out

    # -- one message each ---------------------------------------------------------------------
    def distance_sensor(self, r: RangeReading) -> Message:
        """As PX4's drivers send it: centimetres, ``max_distance`` + 1 cm for no target (NaN)."""
        max_cm = min(0xFFFF, round(r.max_m * 100))
        cm = min(0xFFFF, max_cm + 1) if math.isnan(r.distance_m) else min(max_cm, round(r.distance_m * 100))
        cov = min(254, round((r.noise_std_m * 100) ** 2))  # cm^2; 255 would say "unknown"
        return self.mav.distance_sensor_encode(_ms(r.t_s), round(r.min_m * 100), max_cm, cm, r.sensor_type,
                                               r.sensor_id, r.orientation, cov)  # fmt: skip

    def vision(self, truth: State, kind: str) -> Message | None:
        rng = self._vision_rng
        if self.vision_dropout > 0 and rng.random() < self.vision_dropout:
            return None
        s = self.vision_std_m
        p = truth.pos_ned_m
        x, y, z = (c + (rng.gauss(0.0, s) if s > 0 else 0.0) for c in p)
        roll, pitch, yaw = truth.euler_rad
        usec = round(truth.t_s * 1e6)
        var = s * s
        if kind == "vision":
            cov = [0.0] * 21
            cov[0] = cov[6] = cov[11] = var  # the upper triangle's x, y, z diagonal
            return self.mav.vision_position_estimate_encode(usec, x, y, z, roll, pitch, yaw, cov)
        v = truth.vel_ned_m_s
        cov = list(NO_COVARIANCE)
        cov[0] = cov[6] = cov[11] = var
        return self.mav.odometry_encode(usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD, x, y, z,
                                        list(truth.quat), *v, *truth.rates_rad_s, cov, list(NO_COVARIANCE),
                                        0, mavlink.MAV_ESTIMATOR_TYPE_VISION)  # fmt: skip

    def gps_input(self, fix: GpsFix) -> Message:
        """GPS_INPUT with nothing ignored; its time is the fix's sim time on the GPS clock from the epoch."""
        week, week_ms = _gps_week(fix.t_s)
        vn, ve, vd = fix.vel_ned_m_s
        return self.mav.gps_input_encode(round(fix.t_s * 1e6), 0, 0, week_ms, week, fix.fix_type,
                                         round(fix.lat_deg * 1e7), round(fix.lon_deg * 1e7), fix.alt_m,
                                         fix.eph_m, fix.epv_m, vn, ve, vd, 0.05, fix.eph_m, fix.epv_m,
                                         fix.satellites)  # fmt: skip

    def hil_gps(self, fix: GpsFix) -> Message:
        """HIL_GPS in its integer units (mm, cm/s, cm): what PX4 SITL's simulator bridge takes."""
        vn, ve, vd = fix.vel_ned_m_s
        ground = math.hypot(vn, ve)
        cog = round(math.degrees(math.atan2(ve, vn)) % 360 * 100) if ground > 0.1 else 0xFFFF
        return self.mav.hil_gps_encode(round(fix.t_s * 1e6), fix.fix_type, round(fix.lat_deg * 1e7),
                                       round(fix.lon_deg * 1e7), round(fix.alt_m * 1000),
                                       min(0xFFFF, round(fix.eph_m * 100)), min(0xFFFF, round(fix.epv_m * 100)),
                                       round(ground * 100), round(vn * 100), round(ve * 100), round(vd * 100),
                                       cog, fix.satellites)  # fmt: skip


def _ms(t_s: float) -> int:
    return round(t_s * 1000) & 0xFFFFFFFF


def _gps_week(t_s: float) -> tuple[int, int]:
    """(GPS week, ms of the week) of sim time ``t_s``."""
    week, ms = divmod(round((GPS_TIME_AT_SIM_ZERO_S + t_s) * 1000), WEEK_MS)
    return week, ms

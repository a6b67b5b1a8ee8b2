#!/usr/bin/env python3
"""The MAVLink input paths through which a companion feeds an autopilot's own estimator, measured on SITL.

Not part of CI: it needs the binaries that ``scripts/sitl/ardupilot.sh build`` and ``px4.sh build`` cache.

    .venv/bin/python scripts/sitl/check_inputs.py ardupilot [--instance 6] [--keep DIR]
    .venv/bin/python scripts/sitl/check_inputs.py px4 [--instance 4] [--keep DIR]

For each group of input paths that share parameters it starts one vehicle the way the repo's scripts do
(``ardupilot.sh run 1`` with a parameter file of demos/ardupilot/ in ``SITL_EXTRA_PARM``; ``px4.sh run 1``
with a file of scripts/sitl/px4/ in ``SECUAV_PX4_PARAMS``), this tree's ``secuav-proxy`` in front of it
(no profile: the uplink passes as it came), a companion on the proxy's ground side, and a second companion
link straight to the autopilot (ArduPilot's SERIAL1; PX4's second GCS link). Each feed is computed from the
simulator's truth, which the autopilot streams itself (ArduPilot SITL: SIM_STATE #108 and SIMSTATE #164;
PX4 SIH: HIL_STATE_QUATERNION), plus an offset; every path starts fed at once, then, one path at a time,
the offset is ramped by a known amount, first on the direct link, then back through the proxy. A path
holds on a link when every report the autopilot sends of it (its sensor's echo and its estimator's
output) moved by what the offset moved, within 20 % (0.1 m at least), read back on the same link.

One row per input path and link, then whether it held; exit status 0 only if every row held, 1
otherwise, 2 without a binary. docs/vehicle-inputs.md has a run's output.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sitl_check import free_port, stop, wait_for_text

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
BIN = Path(sys.executable).parent
EARTH_M = 6_378_137.0
GPS_EPOCH_UNIX = 315_964_800  # 1980-01-06
GPS_LEAP_S = 18
COMPANION = 197  # MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY: the feeds' component id (sysid: the vehicle's, as PX4 needs)
WINDOW_S = 2.0  # a report's value before and after a ramp: its median over this long
TOLERANCE = 0.2  # a report holds when it moved by the offset's change within 20 %...
TOLERANCE_MIN = 0.1  # ...or 0.1 m, whichever is larger


# --- pure parts (tests/sitl/test_check_inputs.py) ------------------------------------------------------------


def north_east_m(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """(north, east) in metres of (lat, lon) from (lat0, lon0), degrees; flat earth, fine over metres."""
    return (math.radians(lat - lat0) * EARTH_M, math.radians(lon - lon0) * EARTH_M * math.cos(math.radians(lat0)))


def shifted(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    """(lat, lon) moved by north_m and east_m, degrees: the inverse of :func:`north_east_m`."""
    return (lat + math.degrees(north_m / EARTH_M),
            lon + math.degrees(east_m / (EARTH_M * math.cos(math.radians(lat)))))  # fmt: skip


def gps_week(unix_s: float) -> tuple[int, int]:
    """(GPS week, ms into it) of a Unix time, as GPS_INPUT carries them."""
    gps_s = unix_s - GPS_EPOCH_UNIX + GPS_LEAP_S
    week = int(gps_s // (7 * 86400))
    return week, round((gps_s - week * 7 * 86400) * 1000)


@dataclass
class Ramp:
    """An offset that holds its value and, when told, ramps linearly to a new one over ``seconds``."""

    value: float
    start_s: float = 0.0
    seconds: float = 0.0
    target: float | None = None

    def to(self, target: float, now_s: float, seconds: float) -> None:
        self.value, self.target, self.start_s, self.seconds = self.at(now_s), target, now_s, seconds

    def at(self, now_s: float) -> float:
        if self.target is None or now_s <= self.start_s:
            return self.value
        if self.seconds <= 0 or now_s >= self.start_s + self.seconds:
            return self.target
        return self.value + (self.target - self.value) * (now_s - self.start_s) / self.seconds

    def rate(self, now_s: float) -> float:
        """d(offset)/dt now, per second (a feed's velocity fields say what its position does)."""
        if self.target is None or self.seconds <= 0 or not self.start_s < now_s < self.start_s + self.seconds:
            return 0.0
        return (self.target - self.value) / self.seconds


def verdict(moved: float | None, expected: float) -> bool:
    """Whether a report that moved by ``moved`` followed an offset change of ``expected``."""
    if moved is None or not math.isfinite(moved):
        return False
    return abs(moved - expected) <= max(TOLERANCE * abs(expected), TOLERANCE_MIN)


def median_between(series: Sequence[tuple[float, float]], t0: float, t1: float) -> float | None:
    vals = [v for t, v in series if t0 <= t <= t1]
    return statistics.median(vals) if vals else None


def quat_to_euler(q: Sequence[float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of a (w, x, y, z) quaternion, body to NED."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def ned_to_body(v: Sequence[float], q: Sequence[float]) -> tuple[float, float, float]:
    """A NED vector in the body frame of attitude ``q`` (w, x, y, z; body to NED): q* v q."""
    w, x, y, z = q
    # rotation matrix body->NED, transposed
    r = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
         (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
         (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))  # fmt: skip
    return tuple(sum(r[i][j] * v[i] for i in range(3)) for j in range(3))  # type: ignore[return-value]


# --- the simulator's truth --------------------------------------------------------------------------------------


@dataclass
class Truth:
    """The latest truth: position (deg, m AMSL), velocity NED (m/s), attitude (w, x, y, z)."""

    lat: float
    lon: float
    alt_m: float
    vel_ned: tuple[float, float, float]
    q: tuple[float, float, float, float]


def truth_of(m: Any) -> Truth | None:
    """SIM_STATE (ArduPilot SITL) or HIL_STATE_QUATERNION (PX4 SIH) as :class:`Truth`."""
    kind = m.get_type()
    if kind == "SIM_STATE":
        lat = m.lat_int / 1e7 if getattr(m, "lat_int", 0) else m.lat
        lon = m.lon_int / 1e7 if getattr(m, "lon_int", 0) else m.lon
        return Truth(lat, lon, m.alt, (m.vn, m.ve, m.vd), (m.q1, m.q2, m.q3, m.q4))
    if kind == "HIL_STATE_QUATERNION":
        return Truth(m.lat / 1e7, m.lon / 1e7, m.alt / 1e3, (m.vx / 100, m.vy / 100, m.vz / 100),
                     tuple(m.attitude_quaternion))  # type: ignore[arg-type]  # fmt: skip
    return None


# --- links ------------------------------------------------------------------------------------------------------


class Reader:
    """A pymavlink connection, a thread reading it, and per message type the (wall s, message) it kept:
    only the types asked for, and only from the vehicle's autopilot (compid 1), so hours of 50 Hz streams
    do not pile up."""

    def __init__(self, name: str, conn: Any, sysid: int, types: set[str]) -> None:
        self.name, self.conn, self.sysid, self.types = name, conn, sysid, types
        self.seen: dict[str, list[tuple[float, Any]]] = defaultdict(list)
        self.lock = threading.Lock()
        self.send_lock = threading.Lock()
        self._stop = False
        self._thread = threading.Thread(target=self._pump, name=name, daemon=True)

    def start(self) -> Reader:
        self._thread.start()
        return self

    def _pump(self) -> None:
        while not self._stop:
            try:
                m = self.conn.recv_msg()
            except (OSError, ConnectionError):
                time.sleep(0.05)
                continue
            if m is None:
                time.sleep(0.002)
                continue
            kind = m.get_type()
            if kind in self.types and m.get_srcSystem() == self.sysid and m.get_srcComponent() == 1:
                with self.lock:
                    self.seen[kind].append((time.time(), m))

    def latest(self, kind: str) -> Any | None:
        with self.lock:
            got = self.seen.get(kind)
            return got[-1][1] if got else None

    def series(self, kind: str, value: Callable[[Any], float | None]) -> list[tuple[float, float]]:
        with self.lock:
            items = list(self.seen.get(kind, ()))
        out = []
        for t, m in items:
            v = value(m)
            if v is not None and math.isfinite(v):
                out.append((t, v))
        return out

    def rate_hz(self, kind: str, seconds: float = 5.0) -> float:
        now = time.time()
        with self.lock:
            n = sum(1 for t, _ in self.seen.get(kind, ()) if t > now - seconds)
        return n / seconds

    def send(self, fn: Callable[[Any], None]) -> None:
        with self.send_lock:
            fn(self.conn.mav)

    def close(self) -> None:
        self._stop = True
        self._thread.join(1.0)
        self.conn.close()


def connect(url: str, sysid: int, timeout_s: float = 60.0) -> Any:
    """A companion's connection with the vehicle's sysid and component 197; tcp retried until it opens."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=COMPANION,
                                              dialect="ardupilotmega", retries=0)  # fmt: skip
            if isinstance(conn, mavutil.mavtcp):  # each frame on its own, as the sensor sent it (no Nagle)
                conn.port.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return conn
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)


# --- input paths ------------------------------------------------------------------------------------------------


@dataclass
class Report:
    """One thing the autopilot reports of a path: a message type and its value in the feed's unit."""

    label: str
    kind: str
    value: Callable[[Any, Feeder], float | None]
    also: tuple[str, ...] = ()  # more message types that carry it (PX4: GPS2_RAW for a second receiver)

    @property
    def kinds(self) -> tuple[str, ...]:
        return (self.kind, *self.also)


@dataclass
class InputPath:
    """One MAVLink input path: what is sent, the parameters that enable it, how it is read back."""

    name: str  # e.g. "DISTANCE_SENSOR as rangefinder 1"
    message: str
    params: str  # the parameters that enable it, as in the parameter file
    base: float  # the offset the feed starts with
    swing: float  # how far a row moves the offset
    ramp_s: float
    rate_hz: float
    send: Callable[[Any, Feeder, float, float], None]  # (mav, feeder, offset, offset rate)
    reports: list[Report]
    info_only: bool = False  # a finding, printed but not part of the exit status


@dataclass
class Group:
    """Input paths that one start of the autopilot, with one parameter file, serves."""

    name: str
    param_file: Path
    paths: list[InputPath]
    together: bool = False  # every path switches link with the one being moved (feeds of one companion)
    exclusive: bool = False  # only the path being moved is fed (paths into one estimator input)


class Feeder:
    """Sends every path's feed at its rate, computed from the latest truth plus its offset, on the link the
    path is currently fed through."""

    def __init__(self, truth: Reader, truth_kind: str, links: dict[str, Reader]) -> None:
        self.truth, self.truth_kind, self.links = truth, truth_kind, links
        self.ref: Truth | None = None  # the first truth: the origin of the local frame, the ground's altitude
        self.offsets: dict[str, Ramp] = {}
        self.via: dict[str, str] = {}
        self.paths: list[InputPath] = []
        self.active: set[str] | None = None  # None: every path is fed
        self.sent: dict[tuple[str, str], int] = defaultdict(int)
        self.t0 = time.time()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="feeder", daemon=True)

    def now_truth(self) -> Truth | None:
        m = self.truth.latest(self.truth_kind)
        t = truth_of(m) if m is not None else None
        if t is not None and self.ref is None:
            self.ref = t
        return t

    def usec(self) -> int:
        return int((time.time() - self.t0) * 1e6)

    def add(self, path: InputPath, via: str) -> None:
        self.offsets[path.name] = Ramp(path.base)
        self.via[path.name] = via
        self.paths.append(path)

    def start(self) -> Feeder:
        self._thread.start()
        return self

    def _run(self) -> None:
        # paths of one rate start spread over its period, as independent sensors would be, not in a burst
        # in which the last one sent would always be the last one read
        start = time.time()
        due = {p.name: start + i / (len(self.paths) * p.rate_hz) for i, p in enumerate(self.paths)}
        while not self._stop:
            now = time.time()
            if self.now_truth() is not None:
                if now >= due.get("", 0.0):  # a companion's HEARTBEAT, 1 Hz on each link
                    due[""] = now + 1.0
                    for link in self.links.values():
                        with contextlib.suppress(OSError):
                            link.send(heartbeat)
                for p in self.paths:
                    if self.active is not None and p.name not in self.active:
                        continue
                    if now >= due.get(p.name, 0.0):
                        due[p.name] = now + 1.0 / p.rate_hz
                        ramp = self.offsets[p.name]
                        link = self.links[self.via[p.name]]
                        off, rate = ramp.at(now), ramp.rate(now)
                        try:
                            link.send(lambda m, p=p, off=off, rate=rate: p.send(m, self, off, rate))
                            self.sent[(p.name, self.via[p.name])] += 1
                        except OSError:
                            pass  # the proxy or SITL going away at the end
            time.sleep(0.005)

    def stop(self) -> None:
        self._stop = True
        self._thread.join(1.0)

    # the truth in the feeds' terms
    def height_m(self, t: Truth) -> float:
        assert self.ref is not None
        return t.alt_m - self.ref.alt_m

    def ned_m(self, t: Truth) -> tuple[float, float, float]:
        assert self.ref is not None
        n, e = north_east_m(t.lat, t.lon, self.ref.lat, self.ref.lon)
        return n, e, -(t.alt_m - self.ref.alt_m)

    def north_of(self, lat_deg: float, lon_deg: float) -> float | None:
        if self.ref is None:
            return None
        return north_east_m(lat_deg, lon_deg, self.ref.lat, self.ref.lon)[0]


def heartbeat(m: Any) -> None:
    """The companion's HEARTBEAT (PX4 warns of a lost mission computer when it stops)."""
    m.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)


# feeds: (mav, feeder, offset, offset rate) -> send one message


def send_distance(sensor_id: int) -> Callable[[Any, Feeder, float, float], None]:
    def send(m: Any, f: Feeder, off: float, _rate: float) -> None:
        t = f.now_truth()
        assert t is not None
        cm = max(0, min(65535, round((f.height_m(t) + off) * 100)))
        # laser, downward (25), 0.2-40 m, signal quality 100 (MAVLink's 0 is "unknown")
        m.distance_sensor_send(f.usec() // 1000 & 0xFFFFFFFF, 20, 4000, cm, 0, sensor_id, 25, 0, signal_quality=100)
    return send


def send_vision(m: Any, f: Feeder, off: float, _rate: float) -> None:
    t = f.now_truth()
    assert t is not None
    n, e, d = f.ned_m(t)
    roll, pitch, yaw = quat_to_euler(t.q)
    m.vision_position_estimate_send(f.usec(), n + off, e, d, roll, pitch, yaw)


def send_odometry(m: Any, f: Feeder, off: float, rate: float) -> None:
    t = f.now_truth()
    assert t is not None
    n, e, d = f.ned_m(t)
    vel = ned_to_body((t.vel_ned[0] + rate, t.vel_ned[1], t.vel_ned[2]), t.q)
    nan21 = [math.nan] * 21
    # LOCAL_FRD pose, BODY_FRD velocity: the frames ArduPilot's handler takes (PX4 takes them too)
    m.odometry_send(f.usec(), mav.MAV_FRAME_LOCAL_FRD, mav.MAV_FRAME_BODY_FRD, n + off, e, d, list(t.q),
                    *vel, math.nan, math.nan, math.nan, nan21, nan21, 0, mav.MAV_ESTIMATOR_TYPE_VIO, 100)  # fmt: skip


def send_gps_input(m: Any, f: Feeder, off: float, rate: float) -> None:
    t = f.now_truth()
    assert t is not None
    lat, lon = shifted(t.lat, t.lon, off, 0.0)
    week, week_ms = gps_week(time.time())
    m.gps_input_send(f.usec(), 0, 0, week_ms, week, 3, round(lat * 1e7), round(lon * 1e7), t.alt_m, 0.7, 1.0,
                     t.vel_ned[0] + rate, t.vel_ned[1], t.vel_ned[2], 0.2, 0.5, 0.7, 14)  # fmt: skip


def send_hil_gps(m: Any, f: Feeder, off: float, rate: float) -> None:
    t = f.now_truth()
    assert t is not None
    lat, lon = shifted(t.lat, t.lon, off, 0.0)
    vn, ve, vd = t.vel_ned[0] + rate, t.vel_ned[1], t.vel_ned[2]
    # fix 3D, eph 0.7 m and epv 1.0 m (cm), velocities in cm/s, course unknown (65535), 14 satellites
    m.hil_gps_send(f.usec(), 3, round(lat * 1e7), round(lon * 1e7), round(t.alt_m * 1000), 70, 100,
                   round(math.hypot(vn, ve) * 100), round(vn * 100), round(ve * 100), round(vd * 100),
                   65535, 14)  # fmt: skip


# reports: (message, feeder) -> value in the feed's unit


def rep_rangefinder(m: Any, _f: Feeder) -> float:
    return float(m.distance)


def rep_distance_echo(m: Any, _f: Feeder) -> float | None:
    return m.current_distance / 100 if m.orientation == 25 else None


def rep_height_local(m: Any, f: Feeder) -> float | None:
    return -float(m.z)  # the height the estimator puts on the vehicle, m (LOCAL_POSITION_NED is NED)


def rep_north_local(m: Any, _f: Feeder) -> float:
    return float(m.x)


def rep_north_global(m: Any, f: Feeder) -> float | None:
    return f.north_of(m.lat / 1e7, m.lon / 1e7)


def rep_clearance(m: Any, _f: Feeder) -> float | None:
    return float(m.bottom_clearance)


RANGE_ECHO = [Report("RANGEFINDER.distance", "RANGEFINDER", rep_rangefinder),
              Report("DISTANCE_SENSOR echo", "DISTANCE_SENSOR", rep_distance_echo)]  # fmt: skip


# --- the autopilots ---------------------------------------------------------------------------------------------


class Autopilot:
    name: str
    truth_kinds: tuple[int, ...]  # message ids of the truth it streams
    truth_kind: str  # the one the feeds are computed from
    groups: list[Group]

    def launch(self, group: Group, log: Path) -> subprocess.Popen[bytes]:
        raise NotImplementedError

    def wait_ready(self) -> str | None:
        raise NotImplementedError

    def vehicle_url(self) -> str:
        raise NotImplementedError

    def direct_url(self) -> str:
        raise NotImplementedError

    def build_text(self) -> str:
        raise NotImplementedError


ARDUPILOT_PARAMS = ROOT / "demos" / "ardupilot"
PX4_PARAMS = HERE / "px4"


class ArduPilot(Autopilot):
    name = "ArduPilot"
    truth_kinds = (mav.MAVLINK_MSG_ID_SIM_STATE, mav.MAVLINK_MSG_ID_SIMSTATE)
    truth_kind = "SIM_STATE"

    def __init__(self, cache: Path, instance: int) -> None:
        self.cache, self.instance = cache, instance
        rng = "RNGFND1_TYPE 10, RNGFND1_ORIENT 25 (MIN 0.2, MAX 40)"
        three = "RNGFND1_TYPE 10, RNGFND2_TYPE 10, RNGFND3_TYPE 10 (ORIENT 25); EK3_SRC1_POSZ 2"
        self.groups = [
            Group("rangefinder and GPS_INPUT", ARDUPILOT_PARAMS / "inputs-rangefinder-gps.parm", [
                InputPath("DISTANCE_SENSOR -> rangefinder 1 and EKF3 height", "DISTANCE_SENSOR",
                          f"{rng}; EK3_SRC1_POSZ 2 (height from it)", 3.0, 5.0, 2.0, 20.0, send_distance(0),
                          [*RANGE_ECHO, Report("LOCAL_POSITION_NED height", "LOCAL_POSITION_NED", rep_height_local)]),
                InputPath("GPS_INPUT -> GPS 1 and EKF3 position", "GPS_INPUT", "GPS1_TYPE 14 (MAVLink)",
                          0.0, 10.0, 10.0, 10.0, send_gps_input,
                          [Report("GPS_RAW_INT north", "GPS_RAW_INT", rep_north_global),
                           Report("GLOBAL_POSITION_INT north", "GLOBAL_POSITION_INT", rep_north_global)]),
            ]),
            Group("external navigation", ARDUPILOT_PARAMS / "inputs-extnav.parm", exclusive=True, paths=[
                InputPath("VISION_POSITION_ESTIMATE -> EKF3 position", "VISION_POSITION_ESTIMATE",
                          "VISO_TYPE 1; EK3_SRC1_POSXY 6, VELXY 0, POSZ 1, YAW 1", 0.0, 5.0, 10.0, 20.0, send_vision,
                          [Report("LOCAL_POSITION_NED north", "LOCAL_POSITION_NED", rep_north_local),
                           Report("GLOBAL_POSITION_INT north", "GLOBAL_POSITION_INT", rep_north_global)]),
                InputPath("ODOMETRY -> EKF3 position", "ODOMETRY",
                          "as above; frame LOCAL_FRD, child BODY_FRD", 0.0, 5.0, 10.0, 20.0, send_odometry,
                          [Report("LOCAL_POSITION_NED north", "LOCAL_POSITION_NED", rep_north_local),
                           Report("GLOBAL_POSITION_INT north", "GLOBAL_POSITION_INT", rep_north_global)]),
            ]),
            # the height-hold demo on the vehicle (docs/vehicle-inputs.md): three companion feeds, ids 0, 1, 2,
            # one of them moved; a finding, not a pass/fail row: MAVLink rangefinders do not tell ids apart
            Group("three MAVLink rangefinders, one feed moved", ARDUPILOT_PARAMS / "vehicle-rangefinders.parm",
                  together=True, paths=[
                # rates a little apart, as three sensors' clocks are, so no feed stays in step with the
                # autopilot's 20 Hz rangefinder update and wins every time it reads
                InputPath("DISTANCE_SENSOR id 0", "DISTANCE_SENSOR id 0", three, 3.0, 0.0, 0.0, 9.7,
                          send_distance(0), []),
                InputPath("DISTANCE_SENSOR id 1", "DISTANCE_SENSOR id 1", three, 3.0, 0.0, 0.0, 10.3,
                          send_distance(1), []),
                InputPath("DISTANCE_SENSOR id 2 (biased)", "DISTANCE_SENSOR id 2", three, 3.0, 5.0, 2.0, 10.0,
                          send_distance(2),
                          [*RANGE_ECHO, Report("LOCAL_POSITION_NED height", "LOCAL_POSITION_NED", rep_height_local)],
                          info_only=True),
            ]),
        ]  # fmt: skip

    def launch(self, group: Group, log: Path) -> subprocess.Popen[bytes]:
        (self.cache / "run" / str(self.instance) / "sitl.log").unlink(missing_ok=True)
        env = dict(os.environ, SITL_INSTANCE=str(self.instance), SITL_EXTRA_PARM=str(group.param_file))
        return subprocess.Popen(["bash", str(HERE / "ardupilot.sh"), "run", "1"], stdout=log.open("wb"),
                                stderr=subprocess.STDOUT, start_new_session=True, env=env)  # fmt: skip

    def wait_ready(self) -> str | None:
        log = self.cache / "run" / str(self.instance) / "sitl.log"
        return None if wait_for_text(log, "Waiting for connection", 1, 60) else f"SITL did not start: see {log}"

    def vehicle_url(self) -> str:
        return f"tcp://127.0.0.1:{5760 + 10 * self.instance}"

    def direct_url(self) -> str:
        return f"tcp:127.0.0.1:{5762 + 10 * self.instance}"

    def build_text(self) -> str:
        latest = self.cache / "latest"
        version = (latest / "version").read_text().strip() if (latest / "version").exists() else "?"
        return f"{version}, built from {(latest / 'commit').read_text().strip()} ({latest.resolve()})"


class PX4(Autopilot):
    name = "PX4"
    truth_kinds = (mav.MAVLINK_MSG_ID_HIL_STATE_QUATERNION,)
    truth_kind = "HIL_STATE_QUATERNION"

    def __init__(self, cache: Path, instance: int) -> None:
        self.cache, self.instance = cache, instance
        self.proxy_port = self.direct_port = 0
        # no GLOBAL_POSITION_INT: without GPS fusion EKF2 has no global position to send
        north = [Report("LOCAL_POSITION_NED north", "LOCAL_POSITION_NED", rep_north_local)]
        self.groups = [
            Group("distance sensor and HIL_GPS", PX4_PARAMS / "inputs-distance-gps.params", [
                InputPath("DISTANCE_SENSOR -> distance_sensor and EKF2 range", "DISTANCE_SENSOR",
                          "EKF2_RNG_CTRL 1; SIH_DISTSNSR_OVR 10000 (SIH's own sensor off)", 3.0, 5.0, 2.0, 20.0,
                          send_distance(0),
                          [Report("DISTANCE_SENSOR echo", "DISTANCE_SENSOR", rep_distance_echo),
                           Report("ALTITUDE.bottom_clearance", "ALTITUDE", rep_clearance)]),
                InputPath("HIL_GPS -> sensor_gps and EKF2 position", "HIL_GPS",
                          "MAV_USEHILGPS 1 (and the vehicle's sysid on the frame); SENS_EN_GPSSIM 0", 0.0, 10.0,
                          10.0, 10.0, send_hil_gps,
                          # each MAVLink link's HIL_GPS is a GPS receiver of its own (its device id names the
                          # link): the second one to speak is reported as GPS2_RAW
                          [Report("GPS_RAW_INT/GPS2_RAW north", "GPS_RAW_INT", rep_north_global, ("GPS2_RAW",)),
                           Report("GLOBAL_POSITION_INT north", "GLOBAL_POSITION_INT", rep_north_global)]),
            ]),
            Group("external vision", PX4_PARAMS / "inputs-vision.params", exclusive=True, paths=[
                InputPath("VISION_POSITION_ESTIMATE -> EKF2 external vision", "VISION_POSITION_ESTIMATE",
                          "EKF2_EV_CTRL 1 (horizontal position); EKF2_GPS_CTRL 0", 0.0, 5.0, 10.0, 20.0,
                          send_vision, north),
                InputPath("ODOMETRY -> EKF2 external vision", "ODOMETRY",
                          "as above; frame LOCAL_FRD, child BODY_FRD", 0.0, 5.0, 10.0, 20.0, send_odometry, north),
            ]),
        ]  # fmt: skip

    def launch(self, group: Group, log: Path) -> subprocess.Popen[bytes]:
        self.proxy_port, self.direct_port = free_port(), free_port()
        (self.cache / "run" / str(self.instance) / "px4.log").unlink(missing_ok=True)
        env = dict(os.environ, PX4_INSTANCE=str(self.instance), SECUAV_PX4_PROXY_PORT=str(self.proxy_port),
                   SECUAV_PX4_DIRECT_PORT=str(self.direct_port), SECUAV_PX4_PARAMS=str(group.param_file))
        return subprocess.Popen(["bash", str(HERE / "px4.sh"), "run", "1"], stdout=log.open("wb"),
                                stderr=subprocess.STDOUT, start_new_session=True, env=env)  # fmt: skip

    def wait_ready(self) -> str | None:
        log = self.cache / "run" / str(self.instance) / "px4.log"
        ok = wait_for_text(log, "Startup script returned successfully", 1, 90)
        return None if ok else f"PX4 did not finish its startup script: see {log}"

    def vehicle_url(self) -> str:
        return f"udpin://127.0.0.1:{self.proxy_port}"

    def direct_url(self) -> str:
        return f"udpin:127.0.0.1:{self.direct_port}"

    def build_text(self) -> str:
        latest = self.cache / "latest"
        return f"tree {(latest / 'commit').read_text().strip()} ({latest.resolve()})"


# --- the run ----------------------------------------------------------------------------------------------------


@dataclass
class Row:
    path: InputPath
    via: str
    expected: float
    moved: dict[str, float | None] = field(default_factory=dict)
    span: dict[str, tuple[float, float]] = field(default_factory=dict)  # each report's min, max after the ramp
    share: dict[str, float] = field(default_factory=dict)  # of its values after the ramp, those at the fed one
    sent: int = 0

    @property
    def holds(self) -> bool:
        return bool(self.moved) and all(verdict(v, self.expected) for v in self.moved.values())


def interval(link: Reader, msg_id: int, hz: float) -> None:
    link.send(lambda m: m.command_long_send(link.sysid, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                            1e6 / hz, 0, 0, 0, 0, 0))  # fmt: skip


def report_types(group: Group) -> set[str]:
    return {k for p in group.paths for r in p.reports for k in r.kinds}


def wait_reports(links: Sequence[Reader], kinds: set[str], timeout_s: float) -> list[str]:
    """Until every link has had every kind in the last second; what is still missing at the timeout."""
    end = time.monotonic() + timeout_s
    while True:
        missing = [f"{k} on {lk.name}" for lk in links for k in sorted(kinds) if lk.rate_hz(k, 1.0) == 0]
        if not missing or time.monotonic() > end:
            return missing
        time.sleep(0.5)


def run_group(ap: Autopilot, group: Group, work: Path, settle_s: float, hold_s: float) -> tuple[list[Row], str]:
    """One start of the autopilot: every path of ``group`` fed at once, then each ramped on each link."""
    work.mkdir(parents=True, exist_ok=True)
    print(f"\n=== {ap.name}: {group.name} ({group.param_file.relative_to(ROOT)}) ===", flush=True)
    sitl = proxy = None
    links: dict[str, Reader] = {}
    feeder: Feeder | None = None
    rows: list[Row] = []
    stats = ""
    sysid = 1
    kinds = report_types(group) | {ap.truth_kind, "SIMSTATE", "HEARTBEAT"}
    try:
        sitl = ap.launch(group, work / "sitl-run.log")
        failed = ap.wait_ready()
        if failed:
            print(f"FAIL: {failed}")
            return [], stats
        ground = free_port()
        proxy_log = work / "proxy.log"
        cmd = [str(BIN / "secuav-proxy"), "--vehicle", ap.vehicle_url(), "--ground", f"udpout://127.0.0.1:{ground}",
               "--broker", "none", "--stats-interval", "5"]  # fmt: skip
        proxy = subprocess.Popen(cmd, stdout=proxy_log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)
        links["proxy"] = Reader("proxy", connect(f"udpin:127.0.0.1:{ground}", sysid), sysid, kinds).start()
        # ArduPilot's SERIAL1 opens once SITL boots, which it does when the proxy dials SERIAL0
        links["direct"] = Reader("direct", connect(ap.direct_url(), sysid), sysid, kinds).start()
        end = time.monotonic() + 60
        while links["proxy"].latest("HEARTBEAT") is None and time.monotonic() < end:
            links["proxy"].send(heartbeat)
            time.sleep(1)
        if links["proxy"].latest("HEARTBEAT") is None:
            print(f"FAIL: no HEARTBEAT through the proxy in 60 s; see {proxy_log}")
            return [], stats
        for name, link in links.items():
            if name == "direct":  # PX4's direct link learns where to send from our first frame
                link.send(heartbeat)
        # the truth and the reports, asked for on both links (ArduPilot keeps the rate per link)
        for _ in range(3):
            for link in links.values():
                for msg_id in ap.truth_kinds:
                    interval(link, msg_id, 20)
                for k in report_types(group):
                    interval(link, getattr(mav, f"MAVLINK_MSG_ID_{k}"), 10)
            if links["direct"].latest(ap.truth_kind) is not None:
                break
            time.sleep(2)
        feeder = Feeder(links["direct"], ap.truth_kind, links)
        for p in group.paths:
            feeder.add(p, "direct")
        if group.exclusive:
            feeder.active = {group.paths[0].name}
        t_wait = time.monotonic()
        while feeder.now_truth() is None and time.monotonic() - t_wait < 30:
            time.sleep(0.5)
        if feeder.ref is None:
            print(f"FAIL: no {ap.truth_kind} from {ap.name}: no truth to compute the feeds from")
            return [], stats
        time.sleep(3)
        truth_rates = ", ".join(f"{mav.mavlink_map[i].msgname} #{i} "
                                f"{links['direct'].rate_hz(mav.mavlink_map[i].msgname, 3.0):.1f} Hz"
                                for i in ap.truth_kinds)  # fmt: skip
        feeder.start()
        first = group.paths[0] if group.exclusive else None  # the others' reports come with their feeds
        kinds_now = {r.kind for r in first.reports} if first else {r.kind for p in group.paths for r in p.reports}
        missing = wait_reports(list(links.values()), kinds_now, 120)
        print(f"truth streamed by {ap.name}: {truth_rates}; reports "
              f"{'all arriving' if not missing else 'MISSING: ' + ', '.join(missing)}", flush=True)
        time.sleep(settle_s)  # the estimators converge on the feeds before anything moves
        for p in (p for p in group.paths if p.swing):  # a path with no swing is only fed, as the others' context
            for via in ("direct", "proxy"):
                link = links[via]
                ramp = feeder.offsets[p.name]
                if p.info_only and via == "proxy":  # a finding: the same move again, from where it started
                    ramp.to(p.base, time.time(), 0.0)
                    time.sleep(settle_s / 2)
                old = ramp.at(time.time())
                new = old + p.swing if via == "direct" or p.info_only else old - p.swing
                for q in group.paths if group.together else [p]:
                    feeder.via[q.name] = via
                if group.exclusive:
                    feeder.active = {p.name}
                time.sleep(WINDOW_S + (3.0 if group.exclusive and via == "direct" else 0.5))  # before the ramp
                t_start = time.time()
                sent_before = feeder.sent[(p.name, via)]
                ramp.to(new, t_start, p.ramp_s)
                time.sleep(p.ramp_s + hold_s)
                t_end = time.time()
                row = Row(p, via, new - old, sent=feeder.sent[(p.name, via)] - sent_before)
                for r in p.reports:
                    series = sorted(x for k in r.kinds for x in link.series(k, lambda m, r=r: r.value(m, feeder)))
                    before = median_between(series, t_start - WINDOW_S, t_start)
                    after = median_between(series, t_end - WINDOW_S, t_end)
                    row.moved[r.label] = None if before is None or after is None else after - before
                    late = [v for t, v in series if t_end - WINDOW_S <= t <= t_end]
                    if late and before is not None:
                        row.span[r.label] = (min(late), max(late))
                        hit = sum(1 for v in late if abs(v - (before + row.expected)) <= TOLERANCE_MIN)
                        row.share[r.label] = hit / len(late)
                rows.append(row)
                print_row(row, flush=True)
        stats = last_stats(proxy_log)
        print("  frames sent: " + ", ".join(f"{name} via {via} {n}" for (name, via), n in sorted(feeder.sent.items())))
    finally:
        if feeder is not None:
            feeder.stop()
        for link in links.values():
            link.close()
        stop(proxy)
        time.sleep(0.5)
        stop(sitl)
    return rows, stats


def last_stats(proxy_log: Path) -> str:
    lines = [ln for ln in proxy_log.read_text(errors="replace").splitlines() if "proxy.stats" in ln]
    if not lines:
        return ""
    m = re.search(r"(down=\S+ up=\S+).*?(bad=\S+)", lines[-1])
    return " ".join(m.groups()) if m else lines[-1]


def print_row(row: Row, flush: bool = False) -> None:
    def one(k: str, v: float | None) -> str:
        text = f"{k} {'none' if v is None else f'{v:+.2f}'}"
        if row.path.info_only and k in row.span:
            lo, hi = row.span[k]
            text += f" (then {lo:.2f}..{hi:.2f}, {row.share[k]:.0%} at the fed value)"
        return text

    moved = "; ".join(one(k, v) for k, v in row.moved.items())
    mark = "holds" if row.holds else ("does not hold (a finding)" if row.path.info_only else "FAIL")
    print(f"  {row.path.message:<25} {row.via:<6} fed {row.expected:+.2f} m ({row.sent} frames): moved {moved}: {mark}",
          flush=flush)  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("autopilot", choices=("ardupilot", "px4"))
    parser.add_argument("--instance", type=int, help="SITL instance (ArduPilot default 6: tcp 5820; PX4 default 4)")
    parser.add_argument("--keep", type=Path, help="keep the logs in this directory")
    parser.add_argument("--settle", type=float, default=20.0, help="seconds fed before the first ramp (default 20)")
    parser.add_argument("--hold", type=float, default=6.0, help="seconds each ramp's end is held (default 6)")
    parser.add_argument("--groups", help="comma list of group numbers to run, from 1 (default: all)")
    args = parser.parse_args(argv)
    ap: Autopilot
    if args.autopilot == "ardupilot":
        cache = Path(os.environ.get("SECUAV_ARDUPILOT_CACHE", Path.home() / ".cache/secuav/ardupilot"))
        if not (cache / "latest" / "arducopter").exists() and "ARDUPILOT_BIN" not in os.environ:
            print(f"no SITL binary under {cache}/latest: run scripts/sitl/ardupilot.sh build SOURCE first")
            return 2
        ap = ArduPilot(cache, 6 if args.instance is None else args.instance)
    else:
        cache = Path(os.environ.get("SECUAV_PX4_CACHE", Path.home() / ".cache/secuav/px4"))
        if not (cache / "latest" / "bin" / "px4").exists() and "PX4_BIN" not in os.environ:
            print(f"no PX4 SITL binary under {cache}/latest: run scripts/sitl/px4.sh build SOURCE first")
            return 2
        ap = PX4(cache, 4 if args.instance is None else args.instance)
    print(f"{ap.name}: {ap.build_text()}")
    base = args.keep or Path(tempfile.mkdtemp(prefix=f"secuav-inputs-{args.autopilot}-"))
    rows: list[Row] = []
    ok = True
    chosen = {int(x) for x in args.groups.split(",")} if args.groups else set(range(1, len(ap.groups) + 1))
    for i, group in enumerate(ap.groups, 1):
        if i not in chosen:
            continue
        got, stats = run_group(ap, group, base / f"group{i}", args.settle, args.hold)
        ok &= len(got) == 2 * sum(1 for p in group.paths if p.swing)
        rows += got
        if stats:
            print(f"  proxy's last stats line: {stats}")
    print(f"\n{ap.name}: input path, link, offset fed, what the autopilot reported moving")
    for row in rows:
        print_row(row)
    ok &= all(r.holds for r in rows if not r.path.info_only)
    print(f"\nresult: {'every input path held' if ok else 'FAILED (see above)'}; logs in {base}")
    if not args.keep:
        shutil.rmtree(base, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

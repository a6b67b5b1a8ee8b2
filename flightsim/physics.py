"""JSBSim F450 rigid-body physics for one vehicle.

JSBSim integrates the 6-DOF dynamics of its bundled ``F450`` quad X (1.4 kg,
four DJI E305 motors with 9.4" props, ground contacts, simple drag). Its own
stability augmentation is switched off (``fcs/ScasEngage`` = 0), so the four
motor commands ``fcs/cmd{FR,AL,FL,AR}_ext_nd`` (0..1) are the only inputs.

The vehicle starts at rest on flat ground at the scenario's start position
(north/east; a start ``z`` is ignored: every flight begins on the ground, as
with PX4), whose latitude/longitude come from the home point. Outputs are converted to the
scenario frame: local NED in metres with origin at home, ``z = 0`` when the
vehicle stands on the ground (the centre of gravity is then ~0.15 m above it).
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import math
import os
from collections.abc import Iterator
from types import ModuleType

from flightsim.api import State
from flightsim.control.rotation import Vec3, quat_from_euler
from secuav_common.geo import ned_to_geodetic
from secuav_common.scenario import Home

FT_M = 0.3048
SLUG_KG = 14.593903
SLUGFT2_KGM2 = 1.3558179
REST_HEIGHT_M = 0.1507  # CG above ground when the F450 rests on its gear springs (measured: 0.494 ft)
START_AGL_FT = 0.495  # a hair above where the F450 rests on its gear springs (0.494 ft), so it settles at once
# WGS84, for the local linearisation of JSBSim's geodetic position.
_WGS84_A = 6_378_137.0
_WGS84_E2 = 6.69437999014e-3

MOTOR_PROPS = ("fcs/cmdFR_ext_nd", "fcs/cmdAL_ext_nd", "fcs/cmdFL_ext_nd", "fcs/cmdAR_ext_nd")
STATE_PROPS = (
    "position/lat-geod-rad",
    "position/long-gc-rad",
    "position/h-agl-ft",
    "velocities/v-north-fps",
    "velocities/v-east-fps",
    "velocities/v-down-fps",
    "attitude/phi-rad",
    "attitude/theta-rad",
    "attitude/psi-rad",
    "velocities/p-rad_sec",
    "velocities/q-rad_sec",
    "velocities/r-rad_sec",
)


def _import_jsbsim() -> ModuleType:
    # JSBSim prints a banner at construction unless told otherwise.
    os.environ.setdefault("JSBSIM_DEBUG", "0")
    import jsbsim

    return jsbsim


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence JSBSim's loading chatter (the F450 files trigger version warnings).

    The bindings send C++ output to Python's ``sys.stdout`` when it is not the
    terminal (pytest, the runner) and to file descriptors 1/2 otherwise, so
    both are muted.
    """
    saved = [os.dup(1), os.dup(2)]
    libc = ctypes.CDLL(None)
    sink = io.StringIO()
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            yield
    finally:
        libc.fflush(None)  # C++ streams write through C stdio: flush them while still muted
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


class F450Physics:
    """One JSBSim F450; ``step()`` advances ``dt_s`` with the current motor commands."""

    def __init__(self, home: Home, start_pos_ned_m: Vec3, start_yaw_rad: float, dt_s: float = 1 / 200) -> None:
        jsbsim = _import_jsbsim()
        with _quiet():
            fdm = jsbsim.FGFDMExec(jsbsim.get_default_root_dir())
            fdm.set_debug_level(0)
            if not fdm.load_model("F450"):
                raise RuntimeError("JSBSim could not load the F450 model")
        self._fdm = fdm
        self.dt_s = dt_s
        fdm.set_dt(dt_s)
        self._n0, self._e0 = start_pos_ned_m[0], start_pos_ned_m[1]
        lat, lon, _ = ned_to_geodetic(home, start_pos_ned_m[0], start_pos_ned_m[1], 0.0)
        fdm["ic/lat-geod-deg"] = lat
        fdm["ic/long-gc-deg"] = lon
        fdm["ic/terrain-elevation-ft"] = home.alt_m / FT_M
        fdm["ic/h-agl-ft"] = START_AGL_FT
        fdm["ic/psi-true-deg"] = math.degrees(start_yaw_rad)
        fdm["ic/u-fps"] = 0.0
        fdm["ic/v-fps"] = 0.0
        fdm["ic/w-fps"] = 0.0
        with _quiet():
            fdm.run_ic()
        fdm["fcs/ScasEngage"] = 0.0
        self._lat0 = math.radians(lat)
        self._lon0 = math.radians(lon)
        s = math.sin(self._lat0)
        w = math.sqrt(1 - _WGS84_E2 * s * s)
        alt = home.alt_m
        self._m_per_rad_lat = _WGS84_A * (1 - _WGS84_E2) / (w * w * w) + alt
        self._m_per_rad_lon = (_WGS84_A / w + alt) * math.cos(self._lat0)
        node = fdm.get_property_manager().get_node
        self._motor_setters = tuple(node(p).set_double_value for p in MOTOR_PROPS)
        # Bound getters, read in this order by _read(): 0.1 us each, no string lookups in the loop.
        self._getters = tuple(node(p).get_double_value for p in STATE_PROPS)
        self._wow = tuple(node(f"gear/unit[{i}]/WOW").get_double_value for i in range(3))
        self.mass_kg = float(fdm["inertia/mass-slugs"]) * SLUG_KG
        self.inertia_kgm2: Vec3 = (
            float(fdm["inertia/ixx-slugs_ft2"]) * SLUGFT2_KGM2,
            float(fdm["inertia/iyy-slugs_ft2"]) * SLUGFT2_KGM2,
            float(fdm["inertia/izz-slugs_ft2"]) * SLUGFT2_KGM2,
        )
        self.t_s = 0.0
        self._steps = 0
        self.motors: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._prev_vel: Vec3 = (0.0, 0.0, 0.0)
        self._acc: Vec3 = (0.0, 0.0, 0.0)
        self._state = self._read()

    def set_motors(self, cmds: tuple[float, float, float, float]) -> None:
        """Motor commands 0..1 in JSBSim engine order: FR, AL, FL, AR."""
        a, b, c, d = cmds
        # Clamp to 0..1 inline: this runs every physics step.
        a = 0.0 if a < 0.0 else 1.0 if a > 1.0 else a
        b = 0.0 if b < 0.0 else 1.0 if b > 1.0 else b
        c = 0.0 if c < 0.0 else 1.0 if c > 1.0 else c
        d = 0.0 if d < 0.0 else 1.0 if d > 1.0 else d
        self.motors = (a, b, c, d)
        s0, s1, s2, s3 = self._motor_setters
        s0(a)
        s1(b)
        s2(c)
        s3(d)

    def step(self) -> State:
        """Advance one physics step; returns the new true state."""
        if not self._fdm.run():
            raise RuntimeError("JSBSim stopped integrating")
        self._steps += 1
        self.t_s = self._steps * self.dt_s  # a step count, so the clock never drifts
        self._state = self._read()
        return self._state

    @property
    def state(self) -> State:
        return self._state

    @property
    def on_ground(self) -> bool:
        """Any landing-gear contact carries weight (JSBSim weight-on-wheels)."""
        w0, w1, w2 = self._wow
        return bool(w0() or w1() or w2())

    def _read(self) -> State:
        g = self._getters
        lat, lon, agl, vn, ve, vd = g[0](), g[1](), g[2](), g[3](), g[4](), g[5]()
        phi, theta, psi, p, q, r = g[6](), g[7](), g[8](), g[9](), g[10](), g[11]()
        north = self._n0 + (lat - self._lat0) * self._m_per_rad_lat
        east = self._e0 + (lon - self._lon0) * self._m_per_rad_lon
        down = -(agl * FT_M - REST_HEIGHT_M)
        vel = (vn * FT_M, ve * FT_M, vd * FT_M)
        pv = self._prev_vel
        dt = self.dt_s
        self._acc = ((vel[0] - pv[0]) / dt, (vel[1] - pv[1]) / dt, (vel[2] - pv[2]) / dt)
        self._prev_vel = vel
        yaw = psi if psi <= math.pi else psi - 2 * math.pi  # JSBSim gives 0..2 pi
        return State(
            self.t_s,
            (north, east, down),
            vel,
            self._acc,
            quat_from_euler(phi, theta, yaw),
            (phi, theta, yaw),
            (p, q, r),
        )

"""The vision demo: PX4 SIH holds its position on external vision that a companion feeds through the proxy.

Issue 33's second vehicle-side demo. The autopilot is the victim: ``secuav-feed`` computes
VISION_POSITION_ESTIMATE (30 Hz) and eight UWB anchor ranges (DISTANCE_SENSOR id 10+k, 10 Hz) from SIH's
truth and sends them to PX4 through ``secuav-proxy``; PX4's EKF2 fuses the vision as its only horizontal
position (``scripts/sitl/px4/vision-hold.params``: ``EKF2_EV_CTRL 1``, ``EKF2_GPS_CTRL 0``, baro height).
A ground station (pymavlink, through the proxy) streams one Offboard position setpoint, the estimate where
the vehicle stood plus 5 m up, arms, and leaves the rest to PX4's own position controller.

The attack (``vehicle-vision-ramp``) ramps VISION_POSITION_ESTIMATE.x on its way to the vehicle: PX4's
estimate follows the lie, its controller holds the estimate on the setpoint, so the vehicle itself flies
off by the ramp while LOCAL_POSITION_NED says it holds. The secure stage on the uplink (``--secure NAME
--secure-direction uplink``, anchors group of ``scenarios/px4_vision.yaml``) fixes the position from the
anchor ranges, the second source, and writes it into the vision frames PX4 receives.

Truth is SIH's own: HIL_STATE_QUATERNION, asked for through the proxy at 20 Hz (the proxy changes nothing
of it), converted to NED from the scenario's home, which is SIH's. The feed reads the same truth on PX4's
second, direct link. Each case starts a fresh PX4; the flight ends by stopping PX4 in the air.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import shutil
import socket
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink import mavutil

from attack_profiles.resolve import resolve_profile
from demos.flight import Case, Options
from demos.px4 import PARAMS_DIR, Px4
from demos.stack import tool
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import load_scenario

SCENARIO = "px4_vision"
PARAMS = PARAMS_DIR / "vision-hold.params"
AUTOPILOTS = ("px4",)
DEFAULT_ATTACK = "vehicle-vision-ramp"
DEFAULT_SECURE = "secekf"
DEFAULT_PARAMS: dict[str, Any] = {}
SYSID = 1
PX4_OFFBOARD = 6  # PX4 custom main mode
SETPOINT_HZ = 10.0
POSITION_ONLY = 0x0DF8  # SET_POSITION_TARGET_LOCAL_NED.type_mask: ignore velocity, acceleration, yaw, yaw rate
READY_S = 90.0  # PX4's EKF2 aligning on the fed vision, on a loaded machine
AIRBORNE_S = 60.0


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Gcs:
    """pymavlink ground station on the proxy's ground side; a reader thread keeps what the scoring needs."""

    url: str
    home: Any
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)  # (mono s, n, e, d)
    estimate: list[tuple[float, float, float, float]] = field(default_factory=list)
    armed: bool = False
    mode: int | None = None
    texts: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.conn = mavutil.mavlink_connection(self.url, source_system=255, source_component=190,
                                               dialect="ardupilotmega")  # fmt: skip
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.heard = threading.Event()
        self._thread = threading.Thread(target=self._read, name="vision-gcs", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.5)
            if msg is None or msg.get_srcSystem() != SYSID:
                continue
            now = time.monotonic()
            kind = msg.get_type()
            if kind == "HIL_STATE_QUATERNION":
                n, e, d = geodetic_to_ned(self.home, msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0)
                with self._lock:
                    self.truth.append((now, n, e, d))
            elif kind == "LOCAL_POSITION_NED":
                with self._lock:
                    self.estimate.append((now, msg.x, msg.y, msg.z))
            elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                self.armed = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                self.mode = (msg.custom_mode >> 16) & 0xFF
                self.heard.set()
            elif kind == "STATUSTEXT":
                self.texts.append(f"{now:.1f} {msg.text}")

    def last(self, series: str) -> tuple[float, float, float, float] | None:
        with self._lock:
            rows = getattr(self, series)
            return rows[-1] if rows else None

    def command(self, cmd: int, *params: float) -> None:
        p = (list(params) + [0.0] * 7)[:7]
        self.conn.mav.command_long_send(SYSID, 1, cmd, 0, *p)

    def setpoint(self, n: float, e: float, d: float) -> None:
        self.conn.mav.set_position_target_local_ned_send(0, SYSID, 1, mavutil.mavlink.MAV_FRAME_LOCAL_NED,
                                                         POSITION_ONLY, n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


class Setpoints:
    """Streams one Offboard position setpoint at SETPOINT_HZ (PX4 leaves Offboard when the stream stops)."""

    def __init__(self, gcs: Gcs, target: tuple[float, float, float]) -> None:
        self.gcs, self.target = gcs, target
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="vision-setpoints", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(1.0 / SETPOINT_HZ):
            self.gcs.setpoint(*self.target)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


class Stopped(RuntimeError):
    """The flight was asked to stop (Ctrl-C, SIGTERM: ``run_case`` cancelled)."""


def _sleep(stop: threading.Event, seconds: float) -> None:
    if stop.wait(seconds):
        raise Stopped("stopped")


def _wait(what: str, ok: Any, timeout_s: float, procs: dict[str, subprocess.Popen[bytes]], out: Path,
          stop: threading.Event) -> None:  # fmt: skip
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if ok():
            return
        for name, p in procs.items():
            if p.poll() is not None:
                raise RuntimeError(f"{name} exited ({p.returncode}) while waiting for {what}: see {out / name}.log")
        _sleep(stop, 0.2)
    raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what}; logs in {out}")


def _applied(proxy_log: Path) -> int:
    """How many profiles the proxy's log says it applied (``attack.applied``; the empty one at start says none)."""
    return proxy_log.read_text(errors="replace").count("attack.applied") if proxy_log.is_file() else 0


def fly(case: Case, opts: Options, stop: threading.Event | None = None) -> dict[str, Any]:
    """One flight of one case (blocking); the figures of :func:`score` plus the flight's own facts.

    ``stop`` set: :class:`Stopped` at the next wait, every process stopped on the way out."""
    stop = stop or threading.Event()
    if opts.px4 is None:
        raise ValueError("the vision demo flies PX4 SIH: Options.px4 is required")
    scenario = load_scenario(SCENARIO)
    hold_z = scenario.vehicles[0].target.pos_ned_m[2]  # type: ignore[union-attr]
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    proxy_port, direct_port, gcs_port, feed_port = (free_udp_port() for _ in range(4))
    px4 = Px4(opts.px4, PARAMS, proxy_port, direct_port, out / "px4-run.log")
    procs: dict[str, subprocess.Popen[bytes]] = {}
    gcs: Gcs | None = None
    setpoints: Setpoints | None = None
    profile_file = out / "profile.json"
    profile_file.write_text(json.dumps({"name": "none", "rules": []}), encoding="utf-8")

    def start(name: str, argv: list[str]) -> None:
        procs[name] = subprocess.Popen(argv, stdout=(out / f"{name}.log").open("wb"), stderr=subprocess.STDOUT,
                                       start_new_session=True)  # fmt: skip

    try:
        px4.start()
        px4.wait_started(stop=stop)
        secure = [] if case.secure == "off" else ["--secure", case.secure, "--secure-direction", "uplink"]
        start("proxy", [tool("secuav-proxy"), "--scenario", SCENARIO,
                        "--vehicle", f"udpin://127.0.0.1:{proxy_port}", "--ground", f"udpout://127.0.0.1:{gcs_port}",
                        "--ground", f"udpin://127.0.0.1:{feed_port}", "--broker", "none", "--stats-interval", "5",
                        "--profile", str(profile_file), *secure])  # fmt: skip
        gcs = Gcs(f"udpin:127.0.0.1:{gcs_port}", scenario.world.home)
        start("feed", [tool("secuav-feed"), SCENARIO, "--sensors", "vision,uwb", "--compid", "197",
                       "--to", f"udpout://127.0.0.1:{feed_port}", "--truth", f"udpin://127.0.0.1:{direct_port}",
                       "--status-interval", "10"])  # fmt: skip
        _wait("PX4's HEARTBEAT through the proxy", gcs.heard.is_set, 60.0, procs, out, stop)
        hsq = mavutil.mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
        for _ in range(5):
            gcs.command(mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, hsq, 50_000)
            _sleep(stop, 1.0)
            if gcs.last("truth") is not None:
                break

        def aligned() -> bool:  # EKF2 has taken the vision: its estimate sits on the truth
            t, est = gcs.last("truth"), gcs.last("estimate")
            if t is None or est is None or time.monotonic() - est[0] > 1.0:
                return False
            return math.hypot(est[1] - t[1], est[2] - t[2]) < 0.3

        _wait("PX4's estimate to settle on the fed vision", aligned, READY_S, procs, out, stop)
        _sleep(stop, 3.0)
        est = gcs.last("estimate")
        assert est is not None
        target = (est[1], est[2], hold_z)
        setpoints = Setpoints(gcs, target)
        _sleep(stop, 1.0)
        deadline = time.monotonic() + 30.0
        while not (gcs.armed and gcs.mode == PX4_OFFBOARD) and time.monotonic() < deadline:
            gcs.command(mavutil.mavlink.MAV_CMD_DO_SET_MODE, 1, PX4_OFFBOARD)
            gcs.command(mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            _sleep(stop, 1.5)
        if not (gcs.armed and gcs.mode == PX4_OFFBOARD):
            raise RuntimeError(f"PX4 would not arm in Offboard in 30 s (its last texts: {gcs.texts[-3:]})")
        armed_s = time.monotonic()

        def airborne() -> bool:
            t = gcs.last("truth")
            return t is not None and t[3] < hold_z + 0.3

        _wait(f"the climb to {-hold_z:g} m", airborne, AIRBORNE_S, procs, out, stop)
        _sleep(stop, opts.settle_s)
        t0 = time.monotonic()
        attack_s: float | None = None
        if case.attack is not None:
            profile = resolve_profile(case.attack, opts.attack_params or {}, flag="--attack")
            before = _applied(out / "proxy.log")
            profile_file.write_text(profile.model_dump_json(exclude_none=True), encoding="utf-8")
            end = time.monotonic() + 15.0
            while time.monotonic() < end:  # the proxy reloads the file when it changes; the ramp starts then
                if _applied(out / "proxy.log") > before:
                    attack_s = time.monotonic()
                    break
                _sleep(stop, 0.1)
            if attack_s is None:
                raise RuntimeError(f"the proxy did not apply {case.attack} within 15 s: see {out / 'proxy.log'}")
        end = t0 + opts.seconds
        _wait(f"{opts.seconds:g} s of hold", lambda: time.monotonic() >= end, opts.seconds + 5.0, procs, out, stop)
        t1 = time.monotonic()
        with gcs._lock:
            truth, estimate = list(gcs.truth), list(gcs.estimate)
        texts = list(gcs.texts)
    finally:
        if setpoints is not None:
            setpoints.stop()
        if gcs is not None:
            gcs.close()
        for p in procs.values():
            if p.poll() is None:
                p.terminate()
        px4.stop()
        if px4.run_log.is_file():  # PX4's own log, which the next case's start overwrites
            shutil.copyfile(px4.run_log, out / "px4.log")
        for p in procs.values():
            try:
                p.wait(10.0)
            except subprocess.TimeoutExpired:
                p.kill()
    figures = score(truth, estimate, target, t0, t1, attack_s, opts.attack_params or {}, case)
    figures.update(armed_to_scored_s=round(t0 - armed_s, 1), px4_texts=texts[-10:],
                   proxy_stats=_last_stats(out / "proxy.log"))  # fmt: skip
    (out / "truth.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth), encoding="utf-8")
    (out / "estimate.jsonl").write_text("".join(json.dumps(r) + "\n" for r in estimate), encoding="utf-8")
    return figures


def _last_stats(proxy_log: Path) -> str:
    lines = [ln for ln in proxy_log.read_text(errors="replace").splitlines() if "proxy.stats" in ln]
    return lines[-1].strip() if lines else ""


def _nearest(rows: list[tuple[float, float, float, float]], t: float, start: int) -> tuple[int, tuple[float, ...]]:
    i = start
    while i + 1 < len(rows) and abs(rows[i + 1][0] - t) <= abs(rows[i][0] - t):
        i += 1
    return i, rows[i]


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"rms": None, "max": None, "final": None}
    rms = math.sqrt(sum(v * v for v in values) / len(values))
    return {"rms": round(rms, 3), "max": round(max(values), 3), "final": round(values[-1], 3)}


def _slope(pts: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of (t, v); None with fewer than two distinct times."""
    if len(pts) < 2:
        return None
    mt = sum(t for t, _ in pts) / len(pts)
    mv = sum(v for _, v in pts) / len(pts)
    den = sum((t - mt) ** 2 for t, _ in pts)
    return None if den == 0 else sum((t - mt) * (v - mv) for t, v in pts) / den


def score(truth: list[tuple[float, float, float, float]], estimate: list[tuple[float, float, float, float]],
          target: tuple[float, float, float], t0: float, t1: float, attack_s: float | None,
          params: dict[str, Any], case: Case) -> dict[str, Any]:  # fmt: skip
    """Truth-scored figures of the window ``t0``..``t1`` (monotonic s).

    The hold point is where the vehicle truly was in the second before ``t0``; ``drift_m`` is the true
    horizontal distance from it, ``north_rate_m_s`` the true north displacement's least-squares rate once
    the lie began (the ramp's own rate, with the opposite sign, when the vehicle flies off by the lie),
    ``estimate_error_m`` PX4's LOCAL_POSITION_NED against the truth at the same
    moment, ``estimate_from_setpoint_m`` what PX4's own estimate says of its distance from the setpoint.
    """
    before = [r for r in truth if t0 - 1.0 <= r[0] < t0]
    window = [r for r in truth if t0 <= r[0] <= t1]
    if not before or not window or not estimate:
        raise RuntimeError(f"no truth or estimate in the scored window ({len(before)}, {len(window)}, {len(estimate)})")
    hn = sum(r[1] for r in before) / len(before)
    he = sum(r[2] for r in before) / len(before)
    drift, north, err, said, series = [], [], [], [], {"drift": [], "north": [], "estimate_error": []}
    j = 0
    for t, n, e, _d in window:
        j, est = _nearest(estimate, t, j)
        d = math.hypot(n - hn, e - he)
        x = math.hypot(est[1] - n, est[2] - e)
        drift.append(d)
        north.append(n - hn)
        err.append(x)
        said.append(math.hypot(est[1] - target[0], est[2] - target[1]))
        rel = round(t - t0, 2)
        series["drift"].append((rel, round(d, 3)))
        series["north"].append((rel, round(n - hn, 3)))
        series["estimate_error"].append((rel, round(x, 3)))
    # The true north displacement's rate while the lie grows (least squares over the window after it began).
    since = attack_s if attack_s is not None else t0
    pts = [(t, n - hn) for t, n, _e, _d in window if t >= since]
    rate = _slope(pts)
    ramp = params.get("rate_m_s", 0.2) if case.attack is not None else 0.0
    lie_s = (t1 - attack_s) if attack_s is not None else 0.0
    return {
        "case": case.slug, "attack": case.attack, "secure": case.secure,
        "scored_s": round(t1 - t0, 1), "truth_samples": len(window),
        "hold_point_ned_m": [round(hn, 3), round(he, 3)], "setpoint_ned_m": [round(c, 3) for c in target],
        "drift_m": _stats(drift), "north_displacement_final_m": round(north[-1], 3),
        "north_rate_m_s": None if rate is None else round(rate, 4),
        "lie_at_end_m": round(ramp * lie_s, 2) if attack_s is not None else 0.0,
        "attack_applied_after_s": None if attack_s is None else round(attack_s - t0, 2),
        "estimate_error_m": _stats(err), "estimate_from_setpoint_m": _stats(said),
        "series": series,
    }  # fmt: skip


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    """The flight in a thread; cancelled (Ctrl-C), it tells the thread to stop and waits for its clean-up."""
    stop = threading.Event()
    flight = asyncio.ensure_future(asyncio.to_thread(fly, case, opts, stop))
    try:
        return await asyncio.shield(flight)
    except asyncio.CancelledError:
        stop.set()
        with contextlib.suppress(Exception):
            await flight  # PX4, proxy and feed are stopped before the cancellation goes on
        raise


def summary(f: dict[str, Any]) -> str:
    d, x, s = f["drift_m"], f["estimate_error_m"], f["estimate_from_setpoint_m"]
    return (f"true drift rms {d['rms']} m, max {d['max']} m, north at end {f['north_displacement_final_m']:+} m "
            f"({f['north_rate_m_s']:+} m/s) "
            f"(lie at end {f['lie_at_end_m']} m); PX4's estimate vs truth rms {x['rms']} m, max {x['max']} m; "
            f"PX4's estimate from its setpoint rms {s['rms']} m")  # fmt: skip

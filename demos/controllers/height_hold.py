"""Hold a height above the ground using only downward DISTANCE_SENSOR readings, on ArduPilot.

The wall-hover controller's rule turned to the vertical, for ArduCopter (SITL or real) behind
``secuav-proxy``. A plain pymavlink script, because MAVSDK's offboard mode does not drive
ArduPilot; ArduPilot's GUIDED mode takes the same velocity targets instead. ``secuav-demo height-hold``
flies it (docs/ardupilot.md); by hand:

    scripts/sitl/ardupilot.sh run 1 &                                   # ArduCopter SITL, tcp 5760
    secuav-proxy --scenario ardupilot_height --vehicle tcp://127.0.0.1:5760 --ground udpout://127.0.0.1:14540 &
    python -m demos.controllers.height_hold --url udpin://127.0.0.1:14540 --seconds 30 --log out/controller.jsonl

It sets GUIDED, arms and takes off (MAV_CMD_NAV_TAKEOFF, retried until ArduPilot's pre-arm checks
pass), then commands only a vertical velocity (SET_POSITION_TARGET_LOCAL_NED with every field
but the velocity ignored) from the height it flies by: the mean of the newest reading of each
downward sensor (ids 0-2 by default), leaving out readings older than 0.5 s, out of their range,
or marked invalid (``signal_quality`` 1, which ``secuav-proxy --secure`` sets on sensors it judges
attacked) -- the rule of ``demos/controllers/wall_hover.py``. The hold (event "holding", then
``--seconds`` of it) begins once that height has stayed within 0.15 m of the target for a second
(or after 30 s, logged with ``on_target`` false); then LAND, and "done" once ArduPilot disarms.

ArduPilot's own height stays on its barometer (EK3_SRC1_POSZ 1, its default): the proxy rewrites
what reaches the ground side, so an attack on the wire fools this controller, not the autopilot.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pymavlink import mavutil

from demos.controllers.ranging import Log, Ranges, clip, run_logged

RATE_HZ = 10.0  # ArduPilot streams each rangefinder at 10 Hz (demos/ardupilot/rangefinders.parm)
MAX_SPEED_M_S = 1.0
ON_TARGET_M = 0.15  # the approach is over once the height is this close to the target...
ON_TARGET_S = 1.0  # ...for this long
APPROACH_MAX_S = 30.0  # or after this long, whatever the height
ARM_TIMEOUT_S = 180.0  # ArduPilot refuses to arm until its EKF has converged (about 40 s after SITL boots)
CLIMB_TIMEOUT_S = 60.0
LAND_TIMEOUT_S = 90.0
GUIDED, LAND = 4, 9  # ArduCopter custom modes

_M = mavutil.mavlink
# SET_POSITION_TARGET_LOCAL_NED.type_mask: ignore position, acceleration, yaw and yaw rate; keep velocity.
VELOCITY_ONLY = (
    _M.POSITION_TARGET_TYPEMASK_X_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)


@dataclass
class Hold:
    """The control rule and the moment the hold begins; no I/O, so it is tested without a vehicle."""

    target_m: float
    gain: float = 0.8
    max_speed_m_s: float = MAX_SPEED_M_S
    started_s: float | None = None
    on_since_s: float | None = None
    holding: bool = False

    def height(self, readings: dict[int, float]) -> float | None:
        """The height flown by: the mean of the readings (what a naive fusion does), None without any."""
        return sum(readings.values()) / len(readings) if readings else None

    def down_m_s(self, height_m: float | None) -> float:
        """NED vertical velocity: above the target descend (positive down), below it climb; nothing to fly by: 0."""
        if height_m is None:
            return 0.0
        return clip(self.gain * (height_m - self.target_m), self.max_speed_m_s)

    def settle(self, now_s: float, height_m: float | None) -> bool | None:
        """None while approaching; at the step the hold begins, whether it began on target (then None again)."""
        if self.holding:
            return None
        if self.started_s is None:
            self.started_s = now_s
        near = height_m is not None and abs(height_m - self.target_m) <= ON_TARGET_M
        self.on_since_s = (now_s if self.on_since_s is None else self.on_since_s) if near else None
        if (self.on_since_s is not None and now_s - self.on_since_s >= ON_TARGET_S) or (
            now_s - self.started_s >= APPROACH_MAX_S
        ):
            self.holding = True
            return near
        return None


def pymavlink_url(url: str) -> str:
    """``udpin://127.0.0.1:14540`` (the MAVSDK form the demos pass) as pymavlink's ``udpin:127.0.0.1:14540``."""
    scheme, sep, rest = url.partition("://")
    return f"{scheme}:{rest}" if sep else url


@dataclass
class Link:
    """The ground side of one vehicle: a pymavlink connection, the readings, the vehicle's latest state."""

    conn: Any
    ranges: Ranges = field(default_factory=Ranges)
    sysid: int = 0
    compid: int = 1
    armed: bool = False
    relative_alt_m: float = math.nan
    last_heartbeat_s: float = -math.inf
    acks: list[Any] = field(default_factory=list)

    def pump(self) -> None:
        """Take every message waiting; send our heartbeat once a second."""
        now = time.monotonic()
        if now - self.last_heartbeat_s >= 1.0:
            self.conn.mav.heartbeat_send(_M.MAV_TYPE_GCS, _M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.last_heartbeat_s = now
        while (m := self.conn.recv_match(blocking=False)) is not None:
            self.take(m, time.monotonic())

    def take(self, m: Any, now: float) -> None:
        kind = m.get_type()
        if self.sysid and m.get_srcSystem() != self.sysid:
            return
        if kind == "HEARTBEAT" and m.autopilot != _M.MAV_AUTOPILOT_INVALID:
            self.sysid, self.compid = m.get_srcSystem(), m.get_srcComponent()
            self.armed = bool(m.base_mode & _M.MAV_MODE_FLAG_SAFETY_ARMED)
        elif kind == "DISTANCE_SENSOR":
            self.ranges.add(m.to_dict(), now)
        elif kind == "GLOBAL_POSITION_INT":
            self.relative_alt_m = m.relative_alt / 1000.0
        elif kind == "COMMAND_ACK":
            self.acks.append(m)

    def wait(self, done: Callable[[], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.pump()
            if done():
                return True
            time.sleep(0.02)
        return False

    def command(self, cmd: int, *params: float, timeout_s: float = 3.0) -> int | None:
        """COMMAND_LONG and its COMMAND_ACK's result (None: no answer)."""
        p = [*params, *[0.0] * (7 - len(params))]
        self.acks.clear()
        self.conn.mav.command_long_send(self.sysid, self.compid, cmd, 0, *p)
        self.wait(lambda: any(a.command == cmd for a in self.acks), timeout_s)
        return next((int(a.result) for a in self.acks if a.command == cmd), None)

    def set_mode(self, mode: int) -> int | None:
        return self.command(_M.MAV_CMD_DO_SET_MODE, _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)

    def velocity(self, down_m_s: float) -> None:
        self.conn.mav.set_position_target_local_ned_send(
            0, self.sysid, self.compid, _M.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY,
            0, 0, 0, 0.0, 0.0, down_m_s, 0, 0, 0, 0, 0,
        )  # fmt: skip


def take_off(link: Link, altitude_m: float, log: Log) -> None:
    """GUIDED, arm and MAV_CMD_NAV_TAKEOFF, retried until ArduPilot accepts (its pre-arm checks pass)."""
    accepted = _M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + ARM_TIMEOUT_S
    while time.monotonic() < end:
        # again each time: SITL reads its RC mode switch once RC input starts, which can undo an early GUIDED
        if link.set_mode(GUIDED) == accepted and link.command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == accepted:
            log.write("event", event="armed")
            if link.command(_M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m) == accepted:
                return
        link.wait(lambda: False, 2.0)
    raise SystemExit(f"ArduPilot did not arm and take off within {ARM_TIMEOUT_S:.0f} s")


def hold(link: Link, rule: Hold, group: set[int], seconds: float, log: Log) -> None:
    t_end: float | None = None
    while t_end is None or time.monotonic() < t_end:
        link.pump()
        now = time.monotonic()
        readings, flagged = link.ranges.fresh(now, group)
        height = rule.height(readings)
        down = rule.down_m_s(height)
        link.velocity(down)
        own = link.relative_alt_m  # the vehicle's own (barometric) height: logged, never flown by
        log.write("step", distance_m=height, readings_m=readings, flagged=flagged, down_m_s=round(down, 3),
                  vehicle_alt_m=round(own, 3) if math.isfinite(own) else None)  # fmt: skip
        began = rule.settle(now, height)
        if began is not None:
            log.write("event", event="holding", on_target=began)
            t_end = now + seconds
        time.sleep(1.0 / RATE_HZ)


def land(link: Link, log: Log) -> None:
    """LAND, then wait for the autopilot to disarm; what it refused and how it ended go into ``log``."""
    log.write("event", event="landing")
    mode = link.set_mode(LAND)
    if mode != _M.MAV_RESULT_ACCEPTED:
        log.write("event", event="land-refused", reason=f"MAV_CMD_DO_SET_MODE LAND: result {mode}")
    link.wait(lambda: not link.armed, LAND_TIMEOUT_S)
    log.write("event", event="done", disarmed=not link.armed)


def fly(args: argparse.Namespace, log: Log) -> None:
    conn = mavutil.mavlink_connection(pymavlink_url(args.url), source_system=255, source_component=190,
                                      dialect="ardupilotmega")  # fmt: skip
    link = Link(conn)
    try:
        if not link.wait(lambda: link.sysid != 0, args.connect_timeout):
            raise SystemExit(f"no autopilot answered on {args.url}")
        take_off(link, args.altitude, log)
        link.wait(lambda: link.relative_alt_m >= args.altitude - 0.3, CLIMB_TIMEOUT_S)
        group = {int(i) for i in args.sensors.split(",")}
        hold(link, Hold(args.target, args.gain), group, args.seconds, log)
        land(link, log)
    finally:
        conn.close()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="udpin://127.0.0.1:14540", help="where the proxy's ground side sends")
    p.add_argument("--seconds", type=float, default=30.0, help="how long to hold before landing")
    p.add_argument("--altitude", type=float, default=5.0, help="take-off altitude, metres")
    p.add_argument("--target", type=float, default=5.0, help="height above ground to hold, metres")
    p.add_argument("--sensors", default="0,1,2", help="ids of the downward sensor group")
    p.add_argument("--gain", type=float, default=0.8, help="metres per second per metre of error")
    p.add_argument("--connect-timeout", type=float, default=60.0)
    p.add_argument("--log", help="write JSON lines (events and control steps) to this file")
    run_logged(fly, p.parse_args(argv))


if __name__ == "__main__":
    main()

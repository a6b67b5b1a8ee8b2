"""Take off and let ArduPilot hold the altitude itself: the ground only starts and ends the flight.

The controller of ``secuav-demo rangefinder-feed --autopilot ardupilot`` (docs/ardupilot.md): the altitude
hold runs on the vehicle, in GUIDED after MAV_CMD_NAV_TAKEOFF, on ArduPilot's own estimate (EKF3's
height, here from its MAVLink rangefinders: ``demos/ardupilot/vehicle-rangefinders.parm``). This script
commands nothing while the vehicle holds; it logs what the autopilot says its altitude is
(GLOBAL_POSITION_INT.relative_alt) and what its rangefinders read (its DISTANCE_SENSOR echoes), so the
demo can set them against SITL's truth. Events as the other controllers: "armed", "holding" (the
autopilot's altitude within 0.3 m of the target, or 30 s after take-off), "landing" after ``--seconds``
of hold, "done" once it disarms.

    python -m demos.controllers.vehicle_hold --url udpin://127.0.0.1:14540 --seconds 30 --log out/c.jsonl
"""

from __future__ import annotations

import argparse
import math
import time

from pymavlink import mavutil

from demos.controllers.height_hold import Link, land, pymavlink_url, take_off
from demos.controllers.ranging import Log, run_logged

LOG_HZ = 10.0
REACHED_M = 0.3  # the climb is over once the autopilot's altitude is this close to the target...
CLIMB_MAX_S = 30.0  # ...or after this long


def watch(link: Link, seconds: float, log: Log, group: set[int]) -> None:
    """Log the autopilot's own altitude and rangefinder echoes for ``seconds``; command nothing."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        link.pump()
        readings, _ = link.ranges.fresh(time.monotonic(), group)
        own = link.relative_alt_m
        log.write("step", vehicle_alt_m=round(own, 3) if math.isfinite(own) else None,
                  readings_m=readings)  # fmt: skip
        time.sleep(1.0 / LOG_HZ)


def fly(args: argparse.Namespace, log: Log) -> None:
    conn = mavutil.mavlink_connection(pymavlink_url(args.url), source_system=255, source_component=190,
                                      dialect="ardupilotmega")  # fmt: skip
    link = Link(conn)
    group = {int(i) for i in args.sensors.split(",")}
    try:
        if not link.wait(lambda: link.sysid != 0, args.connect_timeout):
            raise SystemExit(f"no autopilot answered on {args.url}")
        take_off(link, args.altitude, log)
        reached = link.wait(lambda: abs(link.relative_alt_m - args.altitude) <= REACHED_M, CLIMB_MAX_S)
        log.write("event", event="holding", on_target=reached)
        watch(link, args.seconds, log, group)
        land(link, log)
    finally:
        conn.close()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="udpin://127.0.0.1:14540", help="where the proxy's ground side sends")
    p.add_argument("--seconds", type=float, default=30.0, help="how long the vehicle holds before landing")
    p.add_argument("--altitude", type=float, default=5.0, help="take-off altitude the autopilot holds, metres")
    p.add_argument("--sensors", default="0,1,2", help="ids of the rangefinder echoes to log")
    p.add_argument("--connect-timeout", type=float, default=60.0)
    p.add_argument("--log", help="write JSON lines (events and steps) to this file")
    run_logged(fly, p.parse_args(argv))


if __name__ == "__main__":
    main()

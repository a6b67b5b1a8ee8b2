"""Hold a fixed distance from a wall using only the forward DISTANCE_SENSOR readings.

A plain MAVSDK script (mavsdk 4.x asyncio API) to copy and adapt; it is also
the controller `secuav-demo wall-hover` runs. Point it at `secuav-proxy` (or at
`secuav-sim` directly, or at PX4 SITL with a forward rangefinder):

    secuav-sim wall_hover &                     # vehicle -> proxy at 14560
    secuav-proxy --scenario wall_hover &        # proxy -> 14540 (MAVSDK) and 14550 (QGC)
    python examples/wall_hover_controller.py --seconds 40 --log out/controller.jsonl

(`secuav-demo wall-hover` runs the same file as `python -m demos.controllers.wall_hover`.)

The distance it flies by is the mean of the newest reading of each forward
sensor (ids 0-9, orientation forward), leaving out readings older than 0.5 s and
readings marked invalid (`signal_quality` 1, which `secuav-proxy --secure`
sets on sensors it judges attacked). A mean is what a naive fusion does: it is
what an attacker who controls a few of the sensors drags along. The loop never
reads position for the wall axis; altitude is held on LOCAL_POSITION_NED.

MAVSDK's DistanceSensor telemetry carries no sensor id, so the readings come
from the MavlinkDirect plugin, which hands over every DISTANCE_SENSOR field.
Each control step is written as one JSON line to ``--log`` (what the
controller saw and commanded), and the phases ("armed", "holding", "landing",
"done") as events, so a caller can follow the flight.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
import time
from dataclasses import dataclass, field
from typing import IO, Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

FORWARD = 0  # MAV_SENSOR_ROTATION_NONE
INVALID_QUALITY = 1  # DISTANCE_SENSOR.signal_quality: 1 = invalid signal
STALE_S = 0.5
RATE_HZ = 20.0
MAX_SPEED_M_S = 1.0


@dataclass
class Readings:
    """Newest forward reading per sensor id, in metres, with its arrival time."""

    by_id: dict[int, tuple[float, float, bool]] = field(default_factory=dict)  # id -> (t, m, invalid)

    def add(self, fields: dict[str, Any], now: float) -> None:
        sid = int(fields["id"])
        if sid > 9 or int(fields["orientation"]) != FORWARD:
            return
        cm = int(fields["current_distance"])
        if cm <= int(fields["min_distance"]) or cm >= int(fields["max_distance"]):
            return  # out of range: the sensor sees nothing
        self.by_id[sid] = (now, cm / 100.0, int(fields["signal_quality"]) == INVALID_QUALITY)

    def fused(self, now: float) -> tuple[float | None, dict[int, float], list[int]]:
        """(mean of fresh valid readings, fresh readings by id, ids marked invalid)."""
        fresh = {i: (m, bad) for i, (t, m, bad) in self.by_id.items() if now - t <= STALE_S}
        used = [m for m, bad in fresh.values() if not bad]
        flagged = sorted(i for i, (_, bad) in fresh.items() if bad)
        mean = sum(used) / len(used) if used else None
        return mean, {i: m for i, (m, _) in fresh.items()}, flagged


class Log:
    """JSON lines to a file (or nowhere), flushed so a caller can tail it."""

    def __init__(self, out: IO[str] | None) -> None:
        self.out = out
        self.t0 = time.monotonic()

    def write(self, kind: str, **data: Any) -> None:
        if self.out is None:
            return
        stamp = {"t_s": round(time.monotonic() - self.t0, 3), "wall_s": round(time.time(), 3)}
        self.out.write(json.dumps({**stamp, "kind": kind, **data}) + "\n")
        self.out.flush()


async def fly(args: argparse.Namespace, log: Log) -> None:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection(args.url)
    system = await mavsdk.first_autopilot(timeout_s=args.connect_timeout)
    if system is None:
        raise SystemExit(f"wall_hover_controller: no autopilot answered on {args.url}")
    telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
    direct = MavlinkDirectAsync(system)
    readings = Readings()
    down_m = [math.nan]

    async def watch_ranges() -> None:
        async for msg in direct.subscribe_message("DISTANCE_SENSOR"):
            readings.add(json.loads(msg.fields_json), time.monotonic())

    async def watch_position() -> None:
        async for pv in telemetry.subscribe_position_velocity_ned():
            down_m[0] = pv.position.down_m

    async for ok in telemetry.subscribe_health_all_ok():
        if ok:
            break
    watchers = [asyncio.create_task(watch_ranges()), asyncio.create_task(watch_position())]
    try:
        await action.set_takeoff_altitude(args.altitude)
        await action.arm()
        log.write("event", event="armed")
        await action.takeoff()
        while not down_m[0] <= -(args.altitude - 0.2):
            await asyncio.sleep(0.1)
        await offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
        await offboard.start()
        log.write("event", event="holding")
        t_end = time.monotonic() + args.seconds
        while (now := time.monotonic()) < t_end:
            distance, fresh, flagged = readings.fused(now)
            forward = 0.0 if distance is None else args.gain * (distance - args.target)
            forward = max(-MAX_SPEED_M_S, min(MAX_SPEED_M_S, forward))
            down = max(-0.5, min(0.5, args.gain * (down_m[0] + args.altitude)))
            await offboard.set_velocity_body(VelocityBodyYawspeed(forward, 0.0, down, 0.0))
            log.write("step", distance_m=distance, readings_m=fresh, flagged=flagged, forward_m_s=round(forward, 3))
            await asyncio.sleep(1.0 / RATE_HZ)
        log.write("event", event="landing")
        await offboard.stop()
        await action.land()
        async for in_air in telemetry.subscribe_in_air():
            if not in_air:
                break
        log.write("event", event="done")
    finally:
        for task in watchers:
            task.cancel()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    parser.add_argument("--seconds", type=float, default=40.0, help="how long to hold before landing")
    parser.add_argument("--target", type=float, default=2.5, help="distance to hold, metres")
    parser.add_argument("--altitude", type=float, default=2.5, help="hover altitude, metres")
    parser.add_argument("--gain", type=float, default=0.8, help="metres per second per metre of error")
    parser.add_argument("--connect-timeout", type=float, default=20.0)
    parser.add_argument("--log", help="write JSON lines (events and control steps) to this file")
    args = parser.parse_args(argv)
    out = open(args.log, "w", encoding="utf-8") if args.log else None  # noqa: SIM115 - closed below
    try:
        asyncio.run(fly(args, Log(out)))
    except KeyboardInterrupt:
        print("wall_hover_controller: interrupted", file=sys.stderr)
    finally:
        if out is not None:
            out.close()


if __name__ == "__main__":
    main()

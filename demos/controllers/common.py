"""What every demo controller does the same way: connect, take off, log, land.

Plain MAVSDK 4.x asyncio calls, nothing SecUAV-specific, so a controller built
on it flies PX4 SITL as well as ``secuav-sim``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from demos.controllers.ranging import STALE_S, Log, Ranges, clip

__all__ = ["LAND_TIMEOUT_S", "RATE_HZ", "STALE_S", "HoldClock", "Log", "Ranges", "Vehicle", "arguments",
           "clip", "run"]  # fmt: skip

RATE_HZ = 20.0
LAND_TIMEOUT_S = 40.0


@dataclass
class Vehicle:
    """The plugins a controller uses, and what the background watchers keep current."""

    telemetry: TelemetryAsync
    action: ActionAsync
    offboard: OffboardAsync
    ranges: Ranges
    pos_ned_m: list[float]


class HoldClock:
    """When a hold ends: ``seconds`` after it began, or, with ``--hold-from FILE``, after that file appeared.

    The file is for flights of several vehicles. Each controller takes off on its own, and on a loaded machine
    one can reach its hold many seconds after another; counted from each vehicle's own hold, the first would
    land before the last had settled, and the part of the flight where all of them hold (the scored one) could
    be empty. Counted from the file the demo writes once all of them hold, they land together."""

    def __init__(self, seconds: float, start_file: str | None, now: float) -> None:
        self._seconds = seconds
        self._file = None if start_file is None else Path(start_file)
        self._end = now + seconds if self._file is None else None

    def running(self, now: float) -> bool:
        if self._end is None and self._file is not None and self._file.exists():
            self._end = now + self._seconds
        return self._end is None or now < self._end


def arguments(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--url", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    p.add_argument("--seconds", type=float, default=40.0, help="how long to hold before landing")
    p.add_argument("--hold-from", metavar="FILE",
                   help="count --seconds from when FILE appears, not from this vehicle's own hold (a flight of "
                        "several vehicles: the demo writes it once every vehicle holds)")  # fmt: skip
    p.add_argument("--altitude", type=float, default=2.5, help="hover altitude, metres")
    p.add_argument("--gain", type=float, default=0.8, help="metres per second per metre of error")
    p.add_argument("--connect-timeout", type=float, default=20.0)
    p.add_argument("--log", help="write JSON lines (events and control steps) to this file")
    return p


async def _run(args: argparse.Namespace, log: Log, hold: Callable[[Vehicle, Log], Awaitable[None]]) -> None:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection(args.url)
    system = await mavsdk.first_autopilot(timeout_s=args.connect_timeout)
    if system is None:
        raise SystemExit(f"no autopilot answered on {args.url}")
    v = Vehicle(TelemetryAsync(system), ActionAsync(system), OffboardAsync(system), Ranges(), [math.nan] * 3)
    direct = MavlinkDirectAsync(system)  # DISTANCE_SENSOR with its id: MAVSDK's telemetry drops the id

    async def watch_ranges() -> None:
        async for msg in direct.subscribe_message("DISTANCE_SENSOR"):
            v.ranges.add(json.loads(msg.fields_json), time.monotonic())

    async def watch_position() -> None:
        async for pv in v.telemetry.subscribe_position_velocity_ned():
            v.pos_ned_m[:] = [pv.position.north_m, pv.position.east_m, pv.position.down_m]

    async for ok in v.telemetry.subscribe_health_all_ok():
        if ok:
            break
    watchers = [asyncio.create_task(watch_ranges()), asyncio.create_task(watch_position())]
    try:
        await v.action.set_takeoff_altitude(args.altitude)
        await v.action.arm()
        log.write("event", event="armed")
        await v.action.takeoff()
        while not v.pos_ned_m[2] <= -(args.altitude - 0.2):
            await asyncio.sleep(0.1)
        await hold(v, log)
        log.write("event", event="landing")
        try:
            await v.offboard.stop()
            await v.action.land()
        except (OffboardError, ActionError) as exc:  # e.g. the vehicle crashed: it is down already
            log.write("event", event="land-refused", reason=str(exc))
        else:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(_landed(v), LAND_TIMEOUT_S)
        log.write("event", event="done")
    finally:
        for task in watchers:
            task.cancel()


async def _landed(v: Vehicle) -> None:
    async for in_air in v.telemetry.subscribe_in_air():
        if not in_air:
            return


def run(args: argparse.Namespace, hold: Callable[[Vehicle, Log], Awaitable[None]]) -> None:
    """Connect, take off to ``--altitude``, ``hold`` (which starts offboard), land; log to ``--log``."""
    out = open(args.log, "w", encoding="utf-8") if args.log else None  # noqa: SIM115 - closed below
    try:
        asyncio.run(_run(args, Log(out), hold))
    except KeyboardInterrupt:
        print("controller: interrupted")
    finally:
        if out is not None:
            out.close()

"""Hold a fixed distance from a wall using only the forward DISTANCE_SENSOR readings.

A plain MAVSDK script (mavsdk 4.x asyncio API) to copy and adapt; it is also
the controller `secuav-demo wall-hover` runs (as `python -m
demos.controllers.wall_hover`). Point it at `secuav-proxy` (or at `secuav-sim`
directly, or at PX4 SITL with a forward rangefinder):

    secuav-sim wall_hover &                     # vehicle -> proxy at 14560
    secuav-proxy --scenario wall_hover &        # proxy -> 14540 (MAVSDK) and 14550 (QGC)
    python examples/wall_hover_controller.py --seconds 40 --log out/controller.jsonl

The distance it flies by is the mean of the newest reading of each forward
sensor (ids 0-4 by default), leaving out readings older than 0.5 s and readings
marked invalid (`signal_quality` 1, which `secuav-proxy --secure` sets on
sensors it judges attacked). A mean is what a naive fusion does, and what an
attacker who controls a few of the sensors drags along. Altitude is held on
LOCAL_POSITION_NED; position is never used on the wall axis.

The vehicle starts 5 m from the wall, so it first approaches; the hold (event
"holding", then ``--seconds`` of it) begins once the distance it flies by has
stayed within 0.15 m of the target for a second (or after 30 s of approach,
logged with ``on_target`` false). An attack that ``secuav-demo`` starts
``--settle`` seconds later therefore meets a vehicle that holds still.
"""

from __future__ import annotations

import asyncio
import time

from mavsdk.asyncio.plugins.offboard import VelocityBodyYawspeed

from demos.controllers.common import RATE_HZ, HoldClock, Log, Vehicle, arguments, clip, run

MAX_SPEED_M_S = 1.0
ON_TARGET_M = 0.15  # the approach is over once the distance is this close to the target...
ON_TARGET_S = 1.0  # ...for this long
APPROACH_MAX_S = 30.0  # or after this long, whatever the distance (a sensor group the vehicle cannot fly by)


def main(argv: list[str] | None = None) -> None:
    parser = arguments(__doc__.splitlines()[0])
    parser.add_argument("--target", type=float, default=2.5, help="distance to hold, metres")
    parser.add_argument("--sensors", default="0,1,2,3,4", help="ids of the forward sensor group")
    args = parser.parse_args(argv)
    group = {int(i) for i in args.sensors.split(",")}

    async def hold(v: Vehicle, log: Log) -> None:
        await v.offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
        await v.offboard.start()
        t_start = time.monotonic()
        on_since: float | None = None
        clock: HoldClock | None = None  # set when the hold begins
        while clock is None or clock.running(time.monotonic()):
            now = time.monotonic()
            readings, flagged = v.ranges.fresh(now, group)
            distance = sum(readings.values()) / len(readings) if readings else None
            forward = 0.0 if distance is None else clip(args.gain * (distance - args.target), MAX_SPEED_M_S)
            down = clip(-args.gain * (v.pos_ned_m[2] + args.altitude), 0.5)  # below the altitude: climb (down < 0)
            await v.offboard.set_velocity_body(VelocityBodyYawspeed(forward, 0.0, down, 0.0))
            log.write("step", distance_m=distance, readings_m=readings, flagged=flagged, forward_m_s=round(forward, 3))
            if clock is None:
                near = distance is not None and abs(distance - args.target) <= ON_TARGET_M
                on_since = (now if on_since is None else on_since) if near else None
                if (on_since is not None and now - on_since >= ON_TARGET_S) or now - t_start >= APPROACH_MAX_S:
                    log.write("event", event="holding", on_target=near)
                    clock = HoldClock(args.seconds, args.hold_from, now)
            await asyncio.sleep(1.0 / RATE_HZ)

    run(args, hold)


if __name__ == "__main__":
    main()

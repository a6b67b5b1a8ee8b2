"""Take off with MAVSDK and let the autopilot hold the altitude itself: flightsim's side of rangefinder-feed.

``secuav-demo rangefinder-feed --autopilot flightsim`` (docs/ardupilot.md): ``secuav-sim``'s autopilot, like
PX4, holds the take-off altitude in Hold on its own estimate (here its height from a companion's
rangefinders, the scenario's ``external`` block). This script commands nothing during the hold; it logs
the autopilot's own altitude (LOCAL_POSITION_NED, -down) and the rangefinder echoes, then lands.
Events as the other controllers: "armed", "holding", "landing" after ``--seconds``, "done".

    python -m demos.controllers.onboard_hold --url udpin://127.0.0.1:14540 --altitude 5 --seconds 20
"""

from __future__ import annotations

import asyncio
import math
import time

from demos.controllers.common import RATE_HZ, Log, Vehicle, arguments, run

REACHED_M = 0.3  # the hold begins once the autopilot's altitude is this close to the take-off altitude...
CLIMB_MAX_S = 20.0  # ...or after this long


def main() -> None:
    p = arguments(__doc__.splitlines()[0])
    p.add_argument("--sensors", default="0,1,2", help="ids of the rangefinder echoes to log")
    args = p.parse_args()
    group = {int(i) for i in args.sensors.split(",")}

    async def hold(v: Vehicle, log: Log) -> None:
        start = time.monotonic()
        while abs(-v.pos_ned_m[2] - args.altitude) > REACHED_M and time.monotonic() - start < CLIMB_MAX_S:
            await asyncio.sleep(0.1)
        log.write("event", event="holding", on_target=abs(-v.pos_ned_m[2] - args.altitude) <= REACHED_M)
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            readings, _ = v.ranges.fresh(time.monotonic(), group)
            own = -v.pos_ned_m[2]
            log.write("step", vehicle_alt_m=round(own, 3) if math.isfinite(own) else None, readings_m=readings)
            await asyncio.sleep(1.0 / RATE_HZ)

    run(args, hold)


if __name__ == "__main__":
    main()

"""Hold a horizontal position by trilaterating UWB anchor ranges (DISTANCE_SENSOR ids 10+k).

A plain MAVSDK script to copy and adapt; `secuav-demo localise` runs it as
`python -m demos.controllers.localise`. It knows where the anchors stand (from
the scenario file) and fixes its own north/east every step by Gauss-Newton
least squares on the ranges it receives, with the height taken from
LOCAL_POSITION_NED (the downward laser's business, not attacked here):

    secuav-sim anchors8 & secuav-proxy --scenario anchors8 &
    python examples/localise_controller.py --scenario anchors8 --target 2.5,2.5

Plain least squares is what a navigation stack does when it trusts every
anchor, and what an attacker who controls two links drags along. Ranges marked
invalid (`signal_quality` 1, set by `secuav-proxy --secure` on links it judges
attacked) are left out. With `--peer-range ID --peer-at N,E --keep M` it also
keeps M metres from a peer standing at N,E, using the inter-vehicle range ID
for the radial error (seed test case 2, formation).
"""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
from mavsdk.asyncio.plugins.offboard import VelocityNedYaw

from demos.controllers.common import RATE_HZ, HoldClock, Log, Vehicle, arguments, clip, run
from secuav_common.scenario import load_scenario
from secuav_common.sensor_ids import ANCHOR_BASE

MAX_SPEED_M_S = 1.0


def trilaterate(anchors: np.ndarray, ranges: np.ndarray, height_ned_m: float, guess: np.ndarray) -> np.ndarray:
    """North/east that best explains ``ranges`` to ``anchors`` (k x 3, NED) at a known down coordinate."""
    x = guess.astype(float).copy()
    horiz = np.sqrt(np.maximum(ranges**2 - (anchors[:, 2] - height_ned_m) ** 2, 0.0))
    for _ in range(10):
        delta = x[None, :] - anchors[:, :2]
        predicted = np.maximum(np.linalg.norm(delta, axis=1), 1e-6)
        jacobian = delta / predicted[:, None]
        step, *_ = np.linalg.lstsq(jacobian, horiz - predicted, rcond=None)
        x += step
        if float(np.linalg.norm(step)) < 1e-4:
            break
    return x


def _pair(text: str) -> tuple[float, float]:
    a, b = (float(v) for v in text.split(","))
    return a, b


def main(argv: list[str] | None = None) -> None:
    parser = arguments(__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="anchors8", help="scenario file or bundled name (anchor positions)")
    parser.add_argument("--target", type=_pair, default=(2.5, 2.5), help="north,east to hold, metres")
    parser.add_argument("--peer-range", type=int, help="DISTANCE_SENSOR id of the range to a peer (50 + its sysid)")
    parser.add_argument("--peer-at", type=_pair, help="north,east where the peer holds")
    parser.add_argument("--keep", type=float, default=3.0, help="distance to keep from the peer, metres")
    args = parser.parse_args(argv)
    table = load_scenario(args.scenario).anchor_positions()
    anchor_ids = {ANCHOR_BASE + k for k in table}
    target = np.array(args.target)

    async def hold(v: Vehicle, log: Log) -> None:
        await v.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        await v.offboard.start()
        log.write("event", event="holding")
        fix = np.array(v.pos_ned_m[:2])
        clock = HoldClock(args.seconds, args.hold_from, time.monotonic())
        while clock.running(now := time.monotonic()):
            readings, flagged = v.ranges.fresh(now, anchor_ids)
            peer = None
            if args.peer_range is not None:
                peer_readings, peer_flagged = v.ranges.fresh(now, {args.peer_range})
                peer, flagged = peer_readings.get(args.peer_range), flagged + peer_flagged
            fresh = len(readings) >= 3
            if fresh:
                ids = sorted(readings)
                anchors = np.array([table[i - ANCHOR_BASE] for i in ids])
                fix = trilaterate(anchors, np.array([readings[i] for i in ids]), v.pos_ned_m[2], fix)
            goal = target
            if args.peer_at is not None and peer is None:
                # no usable range (silent, or marked invalid by the secure stage): the fix implies it
                peer = float(np.linalg.norm(fix - np.array(args.peer_at)))
            if args.peer_at is not None and peer is not None:
                # stand on the line from the peer through our fix, at the range we must keep
                away = fix - np.array(args.peer_at)
                bearing = away / max(float(np.linalg.norm(away)), 1e-3)
                goal = fix + bearing * (args.keep - peer)
            # Without three trusted ranges (the secure stage marks them all invalid when it cannot correct
            # the attack) the fix is stale: hold rather than steer on it.
            north, east = (clip(args.gain * float(e), MAX_SPEED_M_S) if fresh else 0.0 for e in goal - fix)
            down = clip(-args.gain * (v.pos_ned_m[2] + args.altitude), 0.5)  # below the altitude: climb (down < 0)
            await v.offboard.set_velocity_ned(VelocityNedYaw(north, east, down, 0.0))
            log.write(
                "step", fix_ned_m=[round(float(c), 4) for c in fix], peer_range_m=peer,
                readings_m=readings, flagged=sorted(flagged), telemetry_ned_m=[round(c, 4) for c in v.pos_ned_m],
            )  # fmt: skip
            await asyncio.sleep(1.0 / RATE_HZ)
        if math.isnan(float(fix[0])):
            log.write("event", event="no-fix")

    run(args, hold)


if __name__ == "__main__":
    main()

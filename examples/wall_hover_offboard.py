"""Hold 2.5 m from the wall using only the forward DISTANCE_SENSOR readings.

A plain MAVSDK script (mavsdk 4.x asyncio API) to copy and adapt. It works
against `secuav-sim` directly or through `secuav-proxy`, exactly as against
PX4 SITL:

    secuav-sim scenarios/wall_hover.yaml --mavlink udpout://127.0.0.1:14540
    python examples/wall_hover_offboard.py --seconds 30

The controller is a P loop on the median of the forward group (ids 0-4):
it never reads position, so whatever the link delivers is what it flies by.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from collections import deque

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.telemetry import FlightMode

# MAVSDK's DistanceSensor carries no sensor id, so we keep the newest readings of
# forward-facing sensors (orientation "forward") and take their median.
GROUP_SIZE = 5


async def fly(url: str, seconds: float, target_m: float, gain: float) -> list[tuple[float, float]]:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection(url)
    system = await mavsdk.first_autopilot(timeout_s=15)
    if system is None:
        raise SystemExit(f"no autopilot answered on {url}")
    telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
    print("connected; waiting for health")
    async for ok in telemetry.subscribe_health_all_ok():
        if ok:
            break
    latest: deque[float] = deque(maxlen=GROUP_SIZE)

    async def watch_ranges() -> None:
        async for reading in telemetry.subscribe_distance_sensor():
            if reading.orientation.yaw_deg == 0 and reading.orientation.pitch_deg == 0:
                latest.append(reading.current_distance_m)

    await action.arm()
    await action.takeoff()
    # PX4 (and secuav-sim) ends a takeoff in Hold; start the wall loop from there.
    await asyncio.wait_for(_until_mode(telemetry, FlightMode.HOLD), timeout=30)
    print("took off; holding the wall distance")
    watcher = asyncio.create_task(watch_ranges())
    await offboard.set_velocity_body(VelocityBodyYawspeed(0, 0, 0, 0))
    await offboard.start()
    seen: list[tuple[float, float]] = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if latest:
            distance = statistics.median(latest)
            forward = max(-1.0, min(1.0, gain * (distance - target_m)))
            await offboard.set_velocity_body(VelocityBodyYawspeed(forward, 0, 0, 0))
            seen.append((time.monotonic() - t0, distance))
        await asyncio.sleep(0.05)
    await offboard.stop()
    watcher.cancel()
    await action.land()
    async for in_air in telemetry.subscribe_in_air():
        if not in_air:
            break
    print("landed")
    return seen


async def _until_mode(telemetry: TelemetryAsync, wanted: FlightMode) -> None:
    async for mode in telemetry.subscribe_flight_mode():
        if mode == wanted:
            return


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", default="udpin://0.0.0.0:14540")
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--target", type=float, default=2.5, help="distance to hold, metres")
    parser.add_argument("--gain", type=float, default=0.8)
    args = parser.parse_args()
    seen = asyncio.run(fly(args.url, args.seconds, args.target, args.gain))
    tail = [d for t, d in seen if t > args.seconds / 2]
    if tail:
        print(
            f"distance seen in the second half: median {statistics.median(tail):.2f} m, "
            f"min {min(tail):.2f} m, max {max(tail):.2f} m over {len(tail)} samples"
        )


if __name__ == "__main__":
    main()

"""Real MAVSDK flies both vehicles of formation.yaml at once, as it would fly PX4 SITL.

Each vehicle gets its own MAVSDK instance on its own loopback port; both
flights run concurrently against one simulator at 1x wall clock. What MAVSDK
reports is checked against the simulator's ground truth at the same moment.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.mission import MissionItem, MissionPlan
from mavsdk.plugins.offboard import VelocityBodyYawspeed, VelocityNedYaw
from mavsdk.plugins.telemetry import FlightMode

from flightsim.runner import SimRunner
from flightsim.vehicle import Vehicle
from secuav_common.geo import ned_to_geodetic
from tests.support.live_sim import live_sim, until

TAKEOFF_ALT_M = 2.5
LEG_SPEED_M_S = 1.0
LEG_S = 2.0


@dataclass
class Flight:
    sysid: int
    port: int
    log: list[str]


def _alt(v: Vehicle) -> float:
    return -v.truth.pos_ned_m[2]


async def _connect(m: Mavsdk, port: int) -> System:
    await m.add_any_connection(f"udpin://127.0.0.1:{port}")
    system = await m.first_autopilot(timeout_s=10)
    assert system is not None, f"no autopilot on udpin://127.0.0.1:{port}"
    return system


async def _health_ok(tel: TelemetryAsync) -> None:
    async for ok in tel.subscribe_health_all_ok():
        if ok:
            return


async def _mode(tel: TelemetryAsync, wanted: FlightMode) -> None:
    async for mode in tel.subscribe_flight_mode():
        if mode == wanted:
            return


async def _landed(tel: TelemetryAsync) -> None:
    async for in_air in tel.subscribe_in_air():
        if not in_air:
            return


async def _fly(runner: SimRunner, f: Flight) -> None:
    v = runner.sim.vehicles[f.sysid]
    home = v.home
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await _connect(m, f.port)
        tel, action = TelemetryAsync(system), ActionAsync(system)
        offboard, mission = OffboardAsync(system), MissionAsync(system)
        await asyncio.wait_for(_health_ok(tel), 10)
        f.log.append("health")

        # -- takeoff to MIS_TAKEOFF_ALT; PX4 ends a takeoff in Hold
        await action.arm()
        await action.takeoff()
        await asyncio.wait_for(_mode(tel, FlightMode.HOLD), 15)
        await asyncio.sleep(1.0)
        pos = await tel.position()
        assert abs(pos.relative_altitude_m - TAKEOFF_ALT_M) < 0.2, (f.sysid, pos.relative_altitude_m)
        assert abs(_alt(v) - TAKEOFF_ALT_M) < 0.2, (f.sysid, _alt(v))
        f.log.append("takeoff")

        # -- offboard velocity leg: NED for sysid 1, body frame for sysid 2 (both fly north at yaw 0)
        start = v.truth.pos_ned_m
        yaw_deg = math.degrees(v.truth.euler_rad[2])
        if f.sysid == 1:
            await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw_deg))
        else:
            await offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
        await offboard.start()
        assert await offboard.is_active()
        loop = asyncio.get_running_loop()
        t_end = loop.time() + LEG_S
        while loop.time() < t_end:  # stream at 20 Hz as a MAVSDK script would
            if f.sysid == 1:
                await offboard.set_velocity_ned(VelocityNedYaw(LEG_SPEED_M_S, 0.0, 0.0, yaw_deg))
            else:
                await offboard.set_velocity_body(VelocityBodyYawspeed(LEG_SPEED_M_S, 0.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        if f.sysid == 1:
            await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw_deg))
        else:
            await offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
        await asyncio.sleep(1.5)
        await offboard.stop()
        end = v.truth.pos_ned_m
        moved_n, moved_e = end[0] - start[0], end[1] - start[1]
        assert 1.2 < moved_n < 3.0, (f.sysid, moved_n)
        assert abs(moved_e) < 0.4, (f.sysid, moved_e)
        assert abs(_alt(v) - TAKEOFF_ALT_M) < 0.4, (f.sysid, _alt(v))
        f.log.append("offboard")

        # -- a mission of three waypoints around a square, relative to where we are
        n0, e0, _ = v.estimate.pos_ned_m
        corners = [(n0, e0 - 1.5), (n0 - 1.5, e0 - 1.5), (n0 - 1.5, e0)]
        items = []
        for n, e in corners:
            lat, lon, _ = ned_to_geodetic(home, n, e, 0.0)
            items.append(
                MissionItem(
                    latitude_deg=lat,
                    longitude_deg=lon,
                    relative_altitude_m=TAKEOFF_ALT_M,
                    speed_m_s=2.0,
                    is_fly_through=True,
                    acceptance_radius_m=0.3,
                )
            )
        await mission.upload_mission(MissionPlan(items))
        await mission.start_mission()
        await until_async(mission.is_mission_finished, 25, f"v{f.sysid} mission finished")
        last = v.truth.pos_ned_m
        assert math.hypot(last[0] - corners[-1][0], last[1] - corners[-1][1]) < 0.6, (f.sysid, last)
        f.log.append("mission")

        # -- land, disarm
        await action.land()
        await asyncio.wait_for(_landed(tel), 15)
        if await tel.armed():
            await action.disarm()
        await until(lambda: not v.armed, 5, f"v{f.sysid} disarmed")
        assert _alt(v) < 0.1
        assert not v.crashed
        f.log.append("landed")


async def until_async(check: Callable[[], Awaitable[bool]], timeout_s: float, what: str) -> None:
    """Poll an async predicate (a MAVSDK call) until it is true."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not await check():
        if loop.time() > end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(0.2)


@pytest.mark.slow
@pytest.mark.timeout(120)
async def test_mavsdk_flies_both_formation_vehicles_at_once(udp_port: Callable[[], int]) -> None:
    flights = [Flight(1, udp_port(), []), Flight(2, udp_port(), [])]
    async with live_sim("formation", [f.port for f in flights]) as runner:
        async with asyncio.TaskGroup() as flying:  # one failure cancels the other flight
            for f in flights:
                flying.create_task(_fly(runner, f))
        counts = [runner.vehicles[i].personality.stats for i in range(2)]
    for f in flights:
        assert f.log == ["health", "takeoff", "offboard", "mission", "landed"], f
    for st in counts:
        assert st.rx_malformed == 0
        assert st.offboard_setpoints > 20

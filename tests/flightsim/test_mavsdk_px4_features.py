"""Real MAVSDK against one vehicle: the PX4 features a user script reaches for beyond the basic flight.

Parameters (int, float, the whole list), telemetry rates (SET_MESSAGE_INTERVAL),
a takeoff to a requested altitude, offboard position and position+velocity
setpoints, goto_location (DO_REPOSITION), offboard stop -> Hold, and return to
launch ending landed and disarmed at home. Checked against ground truth.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.offboard import PositionNedYaw, VelocityNedYaw
from mavsdk.plugins.telemetry import FlightMode
from pymavlink.dialects.v20 import common as mavlink

from flightsim.vehicle import Vehicle
from secuav_common.geo import ned_to_geodetic
from tests.support.live_sim import live_sim, until


async def _mode(tel: TelemetryAsync, wanted: FlightMode) -> None:
    async for mode in tel.subscribe_flight_mode():
        if mode == wanted:
            return


async def _near(v: Vehicle, target: tuple[float, float, float], tol_m: float, timeout_s: float, what: str) -> None:
    await until(lambda: math.dist(v.truth.pos_ned_m, target) < tol_m, timeout_s, what)


@pytest.mark.slow
@pytest.mark.timeout(90)
async def test_mavsdk_params_rates_offboard_goto_and_rtl(udp_port: Callable[[], int]) -> None:
    port = udp_port()
    async with (
        live_sim("anchors8", [port]) as runner,
        Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m,
    ):
        v = runner.sim.vehicles[1]
        link = runner.vehicles[0].personality
        await m.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await m.first_autopilot(timeout_s=10)
        assert system is not None
        tel, action, offboard, param = (
            TelemetryAsync(system),
            ActionAsync(system),
            OffboardAsync(system),
            ParamAsync(system),
        )
        async for ok in tel.subscribe_health_all_ok():
            if ok:
                break

        # -- parameters
        every = await param.get_all_params()
        names = {p.name for p in every.int_params} | {p.name for p in every.float_params}
        assert names == {p.name for p in v.params()}
        assert await param.get_param_int("MPC_YAW_MODE") == 0
        await param.set_param_int("MPC_YAW_MODE", 3)
        assert v.get_param("MPC_YAW_MODE").value == 3  # type: ignore[union-attr]
        await param.set_param_int("MPC_YAW_MODE", 0)
        await param.set_param_float("MPC_XY_CRUISE", 2.0)
        assert await param.get_param_float("MPC_XY_CRUISE") == pytest.approx(2.0)

        # -- telemetry rate: set_rate_position -> GLOBAL_POSITION_INT interval
        await tel.set_rate_position(2.0)
        assert link.streams.interval_us(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT) == 500_000

        # -- takeoff to a requested altitude (MIS_TAKEOFF_ALT through the action plugin)
        await action.set_takeoff_altitude(3.0)
        assert v.get_param("MIS_TAKEOFF_ALT").value == pytest.approx(3.0)  # type: ignore[union-attr]
        await action.arm()
        await action.takeoff()
        await asyncio.wait_for(_mode(tel, FlightMode.HOLD), 15)
        await asyncio.sleep(0.5)
        assert abs(-v.truth.pos_ned_m[2] - 3.0) < 0.2

        # -- offboard position NED with a yaw, then position + velocity feed-forward
        n0, e0, _ = v.truth.pos_ned_m
        await offboard.set_position_ned(PositionNedYaw(n0 + 1.0, e0, -3.0, 90.0))
        await offboard.start()
        target = (n0 + 1.0, e0, -3.0)
        for _ in range(100):  # stream at 20 Hz while flying there
            await offboard.set_position_ned(PositionNedYaw(*target, 90.0))
            await asyncio.sleep(0.05)
            if math.dist(v.truth.pos_ned_m, target) < 0.15 and abs(v.truth.euler_rad[2] - math.pi / 2) < 0.1:
                break
        assert math.dist(v.truth.pos_ned_m, target) < 0.15, v.truth.pos_ned_m
        assert abs(math.degrees(v.truth.euler_rad[2]) - 90.0) < 6.0
        target2 = (n0 + 1.0, e0 - 1.0, -3.0)
        for _ in range(100):
            await offboard.set_position_velocity_ned(
                PositionNedYaw(*target2, 90.0), VelocityNedYaw(0.0, 0.0, 0.0, 90.0)
            )
            await asyncio.sleep(0.05)
            if math.dist(v.truth.pos_ned_m, target2) < 0.15:
                break
        assert math.dist(v.truth.pos_ned_m, target2) < 0.15, v.truth.pos_ned_m
        await offboard.stop()
        await asyncio.wait_for(_mode(tel, FlightMode.HOLD), 5)

        # -- set_current_speed: MAV_CMD_DO_CHANGE_SPEED for the auto legs that follow
        await action.set_current_speed(1.5)
        assert v.commander.nav.cruise_m_s() == pytest.approx(1.5)

        # -- goto_location: DO_REPOSITION, hold there
        goal = (n0 - 0.5, e0 - 1.0, -2.0)
        lat, lon, alt = ned_to_geodetic(v.home, *goal)
        await action.goto_location(lat, lon, alt, 0.0)
        await _near(v, goal, 0.2, 12, "goto_location target")
        assert link.vehicle.mode.value == "hold"

        # -- return to launch: home is the scenario origin; ends landed and disarmed there
        await action.set_return_to_launch_altitude(3.5)
        await action.return_to_launch()
        await asyncio.wait_for(_mode(tel, FlightMode.RETURN_TO_LAUNCH), 3)
        await until(lambda: not v.armed, 40, "landed and disarmed after RTL")
        end = v.truth.pos_ned_m
        assert math.hypot(end[0], end[1]) < 0.5 and -end[2] < 0.1
        assert not v.crashed
        assert link.stats.rx_malformed == 0

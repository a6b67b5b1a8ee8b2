"""The attack reaches the vehicle: real flightsim, real secuav-proxy, real MAVSDK on loopback.

(a) ``inject-rtl``: the vehicle hovers after a MAVSDK takeoff; the library profile is applied at
runtime and one forged COMMAND_LONG RTL, sent by the proxy as the ground station, makes the
vehicle (and so what MAVSDK reads) switch to Return. What reached the vehicle from the ground
station's ids (the proxy's recording of what it forwarded) has contiguous sequence numbers and
valid CRCs, the forged command among them.

(b) ``mission-shift``: MAVSDK uploads a raw mission through the proxy; the vehicle holds (and
would fly) every waypoint 20 m north and 10 m east of where the ground put it, while MAVSDK's
download of the same mission gives back exactly the items it sent.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.mission_raw import MissionItem
from mavsdk.plugins.telemetry import FlightMode
from pymavlink.dialects.v20 import common as mavlink

from attack_profiles import library
from flightsim.runner import RunConfig, SimRunner
from mavframe import tlog
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint

pytestmark = [pytest.mark.slow, pytest.mark.timeout(150)]
NORTH_M, EAST_M = 20.0, 10.0


@contextlib.asynccontextmanager
async def stack(udp_port: Callable[[], int], record: Path | None = None) -> AsyncIterator[tuple[Proxy, SimRunner, int]]:
    veh, api = udp_port(), udp_port()
    cfg = ProxyConfig(links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{api}"])],
                      broker="none", record=record)  # fmt: skip
    stop = asyncio.Event()
    async with Proxy(cfg) as proxy:
        run = RunConfig(load_scenario("wall_hover"), [Endpoint("udpout", "127.0.0.1", veh)])
        async with SimRunner(run) as runner:
            task = asyncio.create_task(runner.run(stop))
            try:
                yield proxy, runner, api
            finally:
                stop.set()
                await asyncio.wait_for(task, 5.0)


@contextlib.asynccontextmanager
async def ground(api: int) -> AsyncIterator[Any]:
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        await m.add_any_connection(f"udpin://127.0.0.1:{api}")
        system = await m.first_autopilot(timeout_s=15)
        assert system is not None, "MAVSDK found no autopilot through the proxy"
        yield system


async def first(aiter: AsyncIterator[Any], pred: Callable[[Any], bool], timeout_s: float) -> Any:
    async def go() -> Any:
        async for item in aiter:
            if pred(item):
                return item
        return None

    return await asyncio.wait_for(go(), timeout_s)


async def test_a_forged_rtl_brings_the_vehicle_home(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    async with stack(udp_port, tmp_path / "rec") as (proxy, runner, api), ground(api) as system:
        vehicle = runner.sim.vehicles[1]
        tel, action = TelemetryAsync(system), ActionAsync(system)
        await first(tel.subscribe_health_all_ok(), bool, 20)
        await action.arm()
        await action.takeoff()
        await first(tel.subscribe_flight_mode(), lambda mode: mode == FlightMode.HOLD, 20)
        assert vehicle.mode.name == "HOLD"
        up_before = proxy.stats_snapshot()[1]["uplink"]
        state = proxy.slots[1].offer(library.load("inject-rtl", start_s=0.5))
        assert state.ok, state.error
        mode = await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.RETURN_TO_LAUNCH, 15)
        assert mode == FlightMode.RETURN_TO_LAUNCH and vehicle.mode.name == "RTL"  # the vehicle itself obeyed
        await asyncio.sleep(1.0)  # the ground station goes on talking after the forged frame
        up = proxy.stats_snapshot()[1]["uplink"]
        assert up["injected"] == up_before["injected"] + 1 == 1  # one command, once
        assert up["frames_out"] - up_before["frames_out"] == up["frames_in"] - up_before["frames_in"] + 1
        assert not vehicle.crashed
    log = tlog.read(tmp_path / "rec/v1/forwarded.tlog")
    entries = list(log)
    assert log.skipped == 0
    forged = [e for e in entries if e.header.msgid == mavlink.MAVLINK_MSG_ID_COMMAND_LONG
              and mavlink.MAVLink_command_long_message.unpacker.unpack(
                  e.raw[10:-2].ljust(33, b"\0"))[7] == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH]  # fmt: skip
    assert len(forged) == 1
    gcs = (forged[0].header.sysid, forged[0].header.compid)  # the ground station the proxy heard: MAVSDK's ids
    assert gcs == (245, 190)
    mine = [e for e in entries if (e.header.sysid, e.header.compid) == gcs]
    seqs = [e.header.seq for e in mine]
    assert 0 < mine.index(forged[0]) < len(mine) - 1  # real frames of the ground station before and after it
    assert all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(seqs)), seqs


def _item(seq: int, command: int, lat: float, lon: float, alt: float, frame: int = 6) -> MissionItem:
    return MissionItem(seq, frame, command, int(seq == 0), 1, 0.0, 0.5, 0.0, math.nan,
                       round(lat * 1e7), round(lon * 1e7), alt, 0)  # fmt: skip


def _key(it: Any) -> tuple[Any, ...]:
    """What a read-back must give back exactly (NaN params compare as equal)."""
    p4 = None if math.isnan(it.param4) else it.param4
    return (it.seq, it.frame, it.command, it.autocontinue, it.param1, it.param2, it.param3, p4, it.x, it.y, it.z,
            it.mission_type)  # fmt: skip


async def test_an_uploaded_mission_is_shifted_and_the_read_back_hides_it(udp_port: Callable[[], int]) -> None:
    async with stack(udp_port) as (proxy, runner, api), ground(api) as system:
        vehicle = runner.sim.vehicles[1]
        home = vehicle.home
        state = proxy.slots[1].offer(library.load("mission-shift", north_m=NORTH_M, east_m=EAST_M))
        assert state.ok, state.error
        lat, lon = home.lat_deg, home.lon_deg
        sent = [
            _item(0, mavlink.MAV_CMD_NAV_TAKEOFF, lat, lon, 5.0),  # "here": 0/0 is not used, the home position is
            _item(1, mavlink.MAV_CMD_NAV_WAYPOINT, lat + 1e-4, lon, 5.0),
            _item(2, mavlink.MAV_CMD_NAV_WAYPOINT, lat + 1e-4, lon + 1.5e-4, 5.0),
            _item(3, mavlink.MAV_CMD_DO_CHANGE_SPEED, 0.0, 0.0, 0.0, frame=2),  # no position: never moved
            _item(4, mavlink.MAV_CMD_NAV_LAND, lat, lon + 1.5e-4, 0.0),
        ]
        mission = MissionRawAsync(system)
        await mission.upload_mission(sent)
        back = await mission.download_mission()
        up, down = proxy.stats_snapshot()[1]["uplink"], proxy.stats_snapshot()[1]["downlink"]
        # The ground reads back exactly what it sent ...
        assert [_key(it) for it in back] == [_key(it) for it in sent]
        # ... while the vehicle holds every positioned item 20 m north and 10 m east of it.
        held = runner.vehicles[0].personality.missions.stored[0]
        assert [(h.seq, h.command) for h in held] == [(s.seq, s.command) for s in sent]
        for s, h in zip(sent, held, strict=True):
            if s.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
                assert (h.x, h.y) == (s.x, s.y)
                continue
            n0, e0, _ = geodetic_to_ned(home, s.x * 1e-7, s.y * 1e-7, home.alt_m)
            n1, e1, _ = geodetic_to_ned(home, h.x * 1e-7, h.y * 1e-7, home.alt_m)
            assert (n1 - n0, e1 - e0) == (pytest.approx(NORTH_M, abs=0.05), pytest.approx(EAST_M, abs=0.05)), s.seq
        # The mission the vehicle would fly: its navigation items, in local NED, are the shifted ones.
        nav = vehicle.commander.nav.mission
        assert len(nav) == 4
        assert nav[1].pos_ned_m[0] == pytest.approx(NORTH_M + geodetic_to_ned(home, lat + 1e-4, lon, 0)[0], abs=0.05)
        assert nav[2].pos_ned_m[1] == pytest.approx(EAST_M + geodetic_to_ned(home, lat, lon + 1.5e-4, 0)[1], abs=0.05)
        assert up["rewritten"] >= 4 and down["rewritten"] >= 4 and up["injected"] == down["injected"] == 0

"""Telemetry on the wire: the vehicle's own estimate (not truth), tied to lat/lon by HOME_POSITION.

A parked anchors8 vehicle (2.5, 2.5, 0) NED is watched for a few seconds by a
pymavlink GCS; the figures are compared with the scenario and with the truth.
"""

from __future__ import annotations

import asyncio
import math
import statistics
import time
from collections import defaultdict
from collections.abc import Callable

import pytest
from pymavlink import mavutil

from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import load_scenario
from tests.support.gcs import Gcs
from tests.support.live_sim import live_sim

mav = mavutil.mavlink
WATCH_S = 2.5


def _watch(gcs: Gcs, seconds: float) -> dict[str, list[object]]:
    out: dict[str, list[object]] = defaultdict(list)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        m = gcs.conn.recv_match(blocking=True, timeout=0.1)
        if m is not None and m.get_srcSystem() == 1:
            out[m.get_type()].append(m)
    return out


@pytest.mark.timeout(30)
async def test_position_telemetry_is_the_noisy_estimate_tied_to_home(udp_port: Callable[[], int]) -> None:
    scenario = load_scenario("anchors8")
    home = scenario.world.home
    gps = scenario.vehicles[0].sensors.gps
    port = udp_port()
    gcs = Gcs(port)
    try:
        async with live_sim(scenario, [port]) as runner:
            seen = await asyncio.to_thread(_watch, gcs, WATCH_S)
            truth = runner.sim.vehicles[1].truth
            sim_t_s = runner.sim.t_s
    finally:
        gcs.close()

    # HOME_POSITION is the scenario's home, the NED origin
    hp = seen["HOME_POSITION"][-1]
    assert (hp.latitude, hp.longitude) == (round(home.lat_deg * 1e7), round(home.lon_deg * 1e7))
    assert hp.altitude == round(home.alt_m * 1000) and (hp.x, hp.y, hp.z) == (0, 0, 0)

    # LOCAL_POSITION_NED: near the truth within the configured GPS-grade spread, but not the truth
    local = seen["LOCAL_POSITION_NED"]
    assert 15 * WATCH_S <= len(local) <= 25 * WATCH_S  # 20 Hz
    errs_n = [m.x - truth.pos_ned_m[0] for m in local]
    errs_d = [m.z - truth.pos_ned_m[2] for m in local]
    assert max(abs(e) for e in errs_n) < 5 * gps.horizontal_std_m
    assert max(abs(e) for e in errs_d) < 5 * gps.vertical_std_m
    assert statistics.pstdev(errs_n) > 1e-4 or abs(statistics.fmean(errs_n)) > 1e-4  # not a copy of truth

    # GLOBAL_POSITION_INT is the same estimate in lat/lon through HOME (same time_boot_ms)
    by_time = {m.time_boot_ms: m for m in local}
    pairs = [(g, by_time[g.time_boot_ms]) for g in seen["GLOBAL_POSITION_INT"] if g.time_boot_ms in by_time]
    assert len(pairs) >= 5
    for g, lp in pairs:
        n, e, d = geodetic_to_ned(home, g.lat / 1e7, g.lon / 1e7, g.alt / 1000)
        assert math.hypot(n - lp.x, e - lp.y) < 0.02  # 1e-7 deg is 1.1 cm
        assert abs(d - lp.z) < 0.01
        assert abs(g.relative_alt / 1000 + lp.z) < 0.01

    # GPS: a 3-D fix with the configured satellites; time_boot_ms follows sim time
    raw = seen["GPS_RAW_INT"][-1]
    assert raw.fix_type == 3 and raw.satellites_visible == gps.satellites
    assert abs(local[-1].time_boot_ms / 1000 - sim_t_s) < 0.3
    times = [m.time_boot_ms for m in local]
    assert times == sorted(times)

    # states a GCS shows: on the ground, health bits set, battery full
    assert seen["EXTENDED_SYS_STATE"][-1].landed_state == mav.MAV_LANDED_STATE_ON_GROUND
    ss = seen["SYS_STATUS"][-1]
    for bit in (0x1, 0x2, 0x4, 0x20, 0x10000000):  # gyro, accel, mag, GPS, pre-arm: what MAVSDK's health needs
        assert ss.onboard_control_sensors_present & bit and ss.onboard_control_sensors_health & bit, hex(bit)
    assert seen["BATTERY_STATUS"][-1].battery_remaining == 100
    att = seen["ATTITUDE"][-1]
    assert abs(att.roll) < 0.02 and abs(att.pitch) < 0.02


@pytest.mark.timeout(30)
async def test_udpin_vehicle_answers_whoever_talks_to_it(udp_port: Callable[[], int]) -> None:
    port = udp_port()
    async with live_sim("anchors8", [port], mode="udpin"):
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        try:

            def talk() -> object:
                conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                return conn.recv_match(type="HEARTBEAT", blocking=True, timeout=3)

            hb = await asyncio.to_thread(talk)
            assert hb is not None and hb.get_srcSystem() == 1 and hb.autopilot == mav.MAV_AUTOPILOT_PX4
        finally:
            conn.close()

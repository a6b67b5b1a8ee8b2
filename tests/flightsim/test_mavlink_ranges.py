"""DISTANCE_SENSOR on the wire agrees with the geometry: ids, types, orientations, values
(docs/interfaces.md#mavlink-mapping-mavlink-2-common-dialect).

Both formation vehicles stand on their start points, so the true anchor and
peer distances are fixed and every reading can be checked against them.
"""

from __future__ import annotations

import asyncio
import math
import statistics
import time
from collections.abc import Callable

import pytest
from pymavlink import mavutil

from secuav_common.scenario import load_scenario
from tests.support.gcs import Gcs
from tests.support.live_sim import live_sim

mav = mavutil.mavlink
CUSTOM = 100  # MAV_SENSOR_ROTATION_CUSTOM
DOWN = mav.MAV_SENSOR_ROTATION_PITCH_270


def _collect(gcs: Gcs, seconds: float) -> list[object]:
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        m = gcs.conn.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.1)
        if m is not None and m.get_srcSystem() == gcs.target:
            out.append(m)
    return out


def _collect_sim(gcs: Gcs, sim_s: float, limit_s: float = 20.0) -> list[object]:
    """The readings over ``sim_s`` of the simulator's clock (``time_boot_ms``): a simulator starved of CPU sends
    fewer in a wall-clock second, not in a simulated one."""
    out: list[object] = []
    first: int | None = None
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        m = gcs.conn.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.1)
        if m is None or m.get_srcSystem() != gcs.target:
            continue
        first = m.time_boot_ms if first is None else first
        if m.time_boot_ms - first >= sim_s * 1000:
            return out
        out.append(m)
    raise AssertionError(f"not {sim_s} s of simulated time within {limit_s} s")


@pytest.mark.timeout(60)
async def test_formation_ranges_on_the_wire_match_ids_and_geometry(udp_port: Callable[[], int]) -> None:
    scenario = load_scenario("formation")
    ports = [udp_port(), udp_port()]
    gcss = [Gcs(ports[0], 1), Gcs(ports[1], 2)]
    try:
        async with live_sim(scenario, ports) as runner:
            got = await asyncio.gather(*(asyncio.to_thread(_collect_sim, g, 1.5) for g in gcss))
            truth = {s: v.truth.pos_ned_m for s, v in runner.sim.vehicles.items()}
    finally:
        for g in gcss:
            g.close()
    anchors = scenario.anchor_positions("all")
    for sysid, readings in zip((1, 2), got, strict=True):
        peer = 3 - sysid
        ids = {m.id for m in readings}
        assert ids == {0} | {10 + k for k in range(8)} | {50 + peer}, (sysid, sorted(ids))
        pos = truth[sysid]
        z: list[float] = []
        for m in readings:
            if m.id == 0:  # downward laser on the ground: below min_m, PX4's "no target" = max + 1 cm
                assert (m.type, m.orientation) == (mav.MAV_DISTANCE_SENSOR_LASER, DOWN)
                assert m.current_distance == m.max_distance + 1 == 4001
                assert m.signal_quality == 0
                continue
            assert (m.type, m.orientation) == (mav.MAV_DISTANCE_SENSOR_UNKNOWN, CUSTOM)
            assert m.covariance == 100  # (10 cm)^2
            assert m.signal_quality == 100
            target = anchors[m.id - 10] if m.id < 50 else truth[m.id - 50]
            z.append((m.current_distance / 100.0 - math.dist(pos, target)) / 0.10)
        per_anchor = len(z) / 9
        assert per_anchor >= 12, per_anchor  # 10 Hz over 1.5 s of simulated time
        assert max(abs(x) for x in z) < 4.5
        assert abs(statistics.fmean(z)) < 0.35
        assert 0.7 < statistics.pstdev(z) < 1.3


def _per_id_rates(gcs: Gcs, seconds: float) -> dict[int, float]:
    gcs.drain()
    counts: dict[int, int] = {}
    for m in _collect(gcs, seconds):
        counts[m.id] = counts.get(m.id, 0) + 1
    return {sid: n / seconds for sid, n in counts.items()}


def _throttle(gcs: Gcs) -> None:
    gcs.recv("HEARTBEAT")
    before = _per_id_rates(gcs, 1.5)
    assert before[10] == pytest.approx(10, abs=2.5) and before[0] == pytest.approx(20, abs=4)  # as configured
    dist = mav.MAVLINK_MSG_ID_DISTANCE_SENSOR
    assert gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, dist, 500_000) == 0  # 2 Hz per sensor id
    slow = _per_id_rates(gcs, 2.0)
    assert set(slow) == set(before)
    assert all(1.0 <= r <= 3.0 for r in slow.values()), slow
    assert gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, dist, -1) == 0  # stop
    assert _per_id_rates(gcs, 0.6) == {}
    assert gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, dist, 0) == 0  # back to the sensors' own rates
    after = _per_id_rates(gcs, 1.5)
    assert after[10] == pytest.approx(10, abs=2.5) and after[0] == pytest.approx(20, abs=4)


@pytest.mark.timeout(30)
async def test_distance_sensor_rate_follows_set_message_interval_per_sensor(udp_port: Callable[[], int]) -> None:
    port = udp_port()
    gcs = Gcs(port)
    try:
        async with live_sim("anchors8", [port]):
            await asyncio.to_thread(_throttle, gcs)
    finally:
        gcs.close()

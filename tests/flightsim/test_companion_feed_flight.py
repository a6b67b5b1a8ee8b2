"""The vehicle as the victim: a companion's rangefinder, fed through the real proxy, moves the real vehicle.

One short flight on loopback with every part real: ``secuav-sim``'s runner (JSBSim, the PX4 personality)
publishing truth to an embedded MQTT broker; ``secuav-feed``'s loop reading that truth and sending the
scenario's external rangefinders (DISTANCE_SENSOR, compid 158) to a ground endpoint of ``secuav-proxy``;
a pymavlink ground station arming and taking off through another. The vehicle holds its height on the
fed downward laser (id 0). The attack profile's uplink rule adds 2 m to that laser; the stage starts
bypassed (case a: no attack) and is switched on mid-flight (case b), as the control plane does.

Bounds, from the simulator's truth (never from what the vehicle says):
- (a) the median true height over 2 s is within 0.5 m of the 5 m commanded: the hold itself errs by
  about 0.05 m (flightsim/README.md), a 10x margin, and a quarter of the bias it must then tell apart;
- the wall laser (id 1), fed but not attacked, keeps the true wall distance where takeoff left it (6 m
  from the wall, within 0.5 m) and within 0.3 m of it through the attack: the hold errs by centimetres;
- (b) 6 s after the rule goes on the median true height has dropped by the bias, 2.0 +- 0.5 m: the
  estimate follows a reading within about a second (flightsim/external.py) and the vehicle descends at
  up to 1.5 m/s (MPC_Z_VEL_MAX_DN): it settled within 4 s here, so 6 s leaves room; without the feed in
  the loop it would not move at all, and with the wrong sign it would climb, both far outside the band.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import statistics
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mav

from flightsim.companion.cli import FeedConfig, serve
from flightsim.runner import RunConfig, SimRunner
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.broker import EmbeddedBroker
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint
from tests.support.gcs import Gcs

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

HOLD_M = 5.0
BIAS_M = 2.0
PROFILE = f"""
name: vehicle-rangefinder-bias-test
rules:
  - target: {{message: DISTANCE_SENSOR, sensor_id: 0, field: current_distance, direction: uplink}}
    kind: bias
    offset_m: {BIAS_M}
    start_s: 0
"""


@contextlib.asynccontextmanager
async def bench(tmp_path: Path, udp_port: Callable[[], int], tcp_port: Callable[[], int]) -> AsyncIterator[tuple]:
    veh, gcs_port, feed_port, mqtt = udp_port(), udp_port(), udp_port(), tcp_port()
    profile = tmp_path / "bias.yaml"
    profile.write_text(PROFILE)
    scenario = load_scenario("companion_feed")
    cfg = ProxyConfig(
        links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                          ground=[f"udpout://127.0.0.1:{gcs_port}", f"udpin://127.0.0.1:{feed_port}"])],
        attack="bypass", profile=profile, broker="none",
    )  # fmt: skip
    stop = asyncio.Event()
    async with EmbeddedBroker(port=mqtt) as broker, Proxy(cfg) as proxy:
        run = RunConfig(scenario, [Endpoint("udpout", "127.0.0.1", veh)], broker=broker.address, truth_hz=20.0)
        async with SimRunner(run) as runner:
            sim_task = asyncio.create_task(runner.run(stop))
            feed = FeedConfig(scenario, 1, Endpoint("udpout", "127.0.0.1", feed_port), broker.address.url,
                              ["rangefinders"], None, 158, 1, None, 1.0, 5.0, True)  # fmt: skip
            feed_task = asyncio.create_task(serve(feed, stop))
            try:
                yield proxy, runner, gcs_port
            finally:
                stop.set()
                await asyncio.wait_for(asyncio.gather(sim_task, feed_task), 10.0)


async def true_positions(runner: SimRunner, seconds: float) -> tuple[float, float]:
    """Median true (distance to the wall 6 m north, height) over ``seconds`` of wall clock."""
    walls, heights = [], []
    for _ in range(round(seconds / 0.1)):
        n, _e, d = runner.sim.vehicles[1].truth.pos_ned_m
        walls.append(6.0 - n)
        heights.append(-d)
        await asyncio.sleep(0.1)
    return statistics.median(walls), statistics.median(heights)


async def test_a_fed_rangefinder_holds_the_height_and_an_uplink_bias_moves_the_vehicle(
    tmp_path: Path, udp_port: Callable[[], int], tcp_port: Callable[[], int]
) -> None:
    async with bench(tmp_path, udp_port, tcp_port) as (proxy, runner, gcs_port):
        vehicle = runner.sim.vehicles[1]
        personality = runner.vehicles[0].personality
        gcs = Gcs(gcs_port)
        try:
            def take_off() -> None:
                gcs.recv("HEARTBEAT", 10.0)
                assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
                takeoff = gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, vehicle.home.alt_m + HOLD_M)
                assert takeoff == 0
                gcs.wait_mode("LOITER", 30.0)

            await asyncio.to_thread(take_off)
            in_use = vehicle.external.sources_in_use() if vehicle.external else []
            await asyncio.sleep(2.0)
            wall_held, held = await true_positions(runner, 2.0)
            taken_before = personality.stats.external_taken
            proxy.stages[1].active = True  # what `secuav-attack mode on` does
            await asyncio.sleep(6.0)
            wall_attacked, attacked = await true_positions(runner, 2.0)
            believed = -vehicle.estimate.pos_ned_m[2]
        finally:
            gcs.close()
    assert in_use == ["rangefinder 0", "rangefinder 1"], in_use
    assert abs(held - HOLD_M) < 0.5, held
    assert personality.stats.external_taken > taken_before > 50
    assert abs((held - attacked) - BIAS_M) < 0.5, (held, attacked)
    assert abs(believed - HOLD_M) < 0.5, believed  # the autopilot still thinks it holds 5 m: it was lied to
    assert abs(wall_held - 6.0) < 0.5 and abs(wall_attacked - wall_held) < 0.3, (wall_held, wall_attacked)
    assert not vehicle.crashed
    assert proxy.stats_snapshot()[1]["uplink"]["rewritten"] > 0

"""The secure stage in the real pipeline: flightsim's wall sensors through ``--scenario wall_hover --secure recap``.

The estimator's own behaviour is tested with the secure stage; this checks the
wiring the daemon does: the stage sits after the attack stage, sees the live
DISTANCE_SENSOR stream, substitutes its estimate into what the ground gets,
and its estimates reach the control plane's ``secuav/v1/estimate`` topic on a
real broker.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path

import aiomqtt
import pytest

from flightsim.runner import RunConfig, SimRunner
from mitm_proxy.app import Proxy
from mitm_proxy.cli import build_parser, config_from_args, main
from secuav_common.broker import EmbeddedBroker
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(60), pytest.mark.usefixtures("proxy_path")]
REPO = Path(__file__).resolve().parents[2]


async def test_secure_stage_runs_on_live_ranges_and_publishes(udp_port: Callable[[], int],
                                                              tcp_port: Callable[[], int]) -> None:  # fmt: skip
    veh, gcs, mqtt = udp_port(), udp_port(), tcp_port()
    scenario = str(REPO / "scenarios/wall_hover.yaml")
    cfg = config_from_args(build_parser().parse_args([
        "--scenario", scenario, "--secure", "recap", "--broker", f"mqtt://127.0.0.1:{mqtt}",
        "--vehicle", f"udpin://127.0.0.1:{veh}", "--ground", f"udpout://127.0.0.1:{gcs}"]))  # fmt: skip
    estimates: list[dict[str, object]] = []
    async with EmbeddedBroker(port=mqtt), aiomqtt.Client("127.0.0.1", mqtt) as client:
        await client.subscribe("secuav/v1/#")

        async def listen() -> None:
            async for msg in client.messages:
                if str(msg.topic) == "secuav/v1/estimate":
                    estimates.append(json.loads(bytes(msg.payload)))  # type: ignore[arg-type]

        listener = asyncio.create_task(listen())
        async with Proxy(cfg) as proxy:
            await proxy.control.wait_connected(10)
            stop = asyncio.Event()
            run = RunConfig(load_scenario(scenario), [Endpoint("udpout", "127.0.0.1", veh)])
            async with SimRunner(run) as runner:
                task = asyncio.create_task(runner.run(stop))
                await asyncio.sleep(4.0)  # past the layout check's 3 s grace
                stop.set()
                await asyncio.wait_for(task, 5.0)
            snap = proxy.stats_snapshot()[1]
        listener.cancel()
    secure = snap["secure"]
    assert secure["estimator"] == "recap"
    assert secure["readings"] > 50 and secure["substituted_frames"] > 20, secure
    assert snap["downlink"]["rewritten"] >= secure["substituted_frames"] > 0
    assert len(estimates) > 10
    assert snap["warnings"] == []  # flightsim's wall sensors are the scenario's: no layout warning
    # Readings timed by flightsim's time_boot_ms (sim time) on the proxy's clock (measured: 360 of 360, no re-anchor)
    assert secure["reading_time"] == "stamp" and secure["clock_sources"] == 1, secure
    timed = secure["readings_stamped"] + secure["readings_unstamped"] + secure["readings_off_clock"]
    assert timed == secure["readings"], secure
    assert secure["readings_stamped"] > 0.9 * secure["readings"], secure


def test_secure_without_a_scenario_or_with_an_unknown_estimator_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--secure", "recap", "--broker", "none"]) == 2
    assert "needs --scenario" in capsys.readouterr().err
    assert main(["--secure", "crystal-ball", "--scenario", "wall_hover", "--broker", "none"]) == 2
    err = capsys.readouterr().err
    assert "crystal-ball" in err and err.count("\n") == 1

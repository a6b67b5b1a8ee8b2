"""Run the real simulator in the test's event loop at 1x, on loopback ports.

The runner is the same one ``secuav-sim`` uses (JSBSim, PX4 personality, UDP
sockets); running it in-process lets a test compare what the ground side is
told with the vehicle's true state at the same moment.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable

from flightsim.runner import RunConfig, SimRunner
from secuav_common.scenario import Scenario, load_scenario
from secuav_common.urls import Endpoint


@contextlib.asynccontextmanager
async def live_sim(
    scenario: str | Scenario, ports: list[int], mode: str = "udpout", speed: float = 1.0
) -> AsyncIterator[SimRunner]:
    """Vehicle i talks ``mode``://127.0.0.1:ports[i]; the runner ticks until the block ends."""
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    endpoints = [Endpoint(mode, "127.0.0.1", p) for p in ports]  # type: ignore[arg-type]
    stop = asyncio.Event()
    async with SimRunner(RunConfig(sc, endpoints, speed=speed)) as runner:
        task = asyncio.create_task(runner.run(stop))
        try:
            yield runner
        finally:
            stop.set()
            await asyncio.wait_for(task, 5.0)


async def until(predicate: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.05) -> None:
    """Wait (wall clock) until ``predicate()`` is true; fail naming ``what`` otherwise."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not predicate():
        if loop.time() > end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(poll_s)

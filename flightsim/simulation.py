"""All vehicles of a scenario, stepped together on one clock.

``Simulation(scenario, seed=None)`` builds one :class:`~flightsim.vehicle.Vehicle`
per scenario vehicle (keyed by sysid). ``step()`` advances every vehicle by one
physics step of ``dt_s``; the peers' true states are snapshotted before the
step so the result does not depend on the order vehicles are stepped in.

Deterministic: the same scenario and seed (default: the scenario's ``seed``)
give the same physics and the same noise. The clock is simulated time only;
pacing against the wall clock is the runner's job.
"""

from __future__ import annotations

from collections.abc import Callable

from flightsim.api import State
from flightsim.vehicle import Vehicle
from flightsim.world import World
from secuav_common.scenario import Scenario

# 200 Hz: the attitude/rate loops want >= 5x the ~55 ms motor lag's bandwidth, and the
# gear springs of the F450 model stay stable; 250 Hz (PX4 SITL's rate) costs 20 % more CPU for no visible gain.
PHYSICS_RATE_HZ = 200.0


class Simulation:
    def __init__(self, scenario: Scenario, seed: int | None = None, dt_s: float = 1.0 / PHYSICS_RATE_HZ) -> None:
        self.scenario = scenario
        self.seed = scenario.seed if seed is None else seed
        self.dt_s = dt_s
        self.world = World(scenario.world)
        self.vehicles: dict[int, Vehicle] = {
            cfg.sysid: Vehicle(cfg, scenario, self.world, self.seed, dt_s) for cfg in scenario.vehicles
        }
        self._steps = 0

    @property
    def t_s(self) -> float:
        """Simulated time since start (s); an integer step count times ``dt_s``, so it never drifts."""
        return self._steps * self.dt_s

    def truths(self) -> dict[int, State]:
        return {sysid: v.truth for sysid, v in self.vehicles.items()}

    def step(self) -> None:
        peers = self.truths() if len(self.vehicles) > 1 else {}
        for vehicle in self.vehicles.values():
            vehicle.step(peers)
        self._steps += 1

    def run_until(self, t_s: float, on_step: Callable[[Simulation], object] | None = None) -> None:
        """Step until simulated time reaches ``t_s``; ``on_step`` is called after every step."""
        end = round(t_s / self.dt_s)
        while self._steps < end:
            self.step()
            if on_step is not None:
                on_step(self)

    def run_for(self, duration_s: float, on_step: Callable[[Simulation], object] | None = None) -> None:
        self.run_until(self.t_s + duration_s, on_step)

    def vehicle(self, sysid: int) -> Vehicle:
        return self.vehicles[sysid]

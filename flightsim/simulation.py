"""All vehicles of a scenario, stepped together on one clock.

``Simulation(scenario, seed=None)`` builds one :class:`~flightsim.vehicle.Vehicle`
per scenario vehicle (keyed by sysid). ``step()`` advances every vehicle by one
physics step of ``dt_s``; the peers' true states are snapshotted before the
step so the result does not depend on the order vehicles are stepped in.

Deterministic: the same scenario and seed (default: the scenario's ``seed``)
give the same physics and the same noise. The clock is simulated time only;
pacing against the wall clock is the runner's job.

Headless use, e.g. an offline evaluation (no MAVLink)::

    sim = Simulation(load_scenario("anchors8"), seed=7)
    sim.take_off()                                  # arm all, MIS_TAKEOFF_ALT, settle in Hold
    v = sim.vehicles[1]
    leg = OffboardSetpoint(vel_m_s=(0.5, 0.0, 0.0), yaw_rad=0.0)
    v.offboard_setpoint(leg)
    v.set_mode(FlightMode.OFFBOARD)
    log = []
    sim.run_for(10.0, lambda s: (v.offboard_setpoint(leg), log.append((v.truth, v.pop_readings()))))
"""

from __future__ import annotations

import math
from collections.abc import Callable

from flightsim.api import FlightMode, State
from flightsim.vehicle import Vehicle
from flightsim.world import NEAR_GROUND_M, World
from secuav_common.scenario import Scenario

# 200 Hz: the attitude/rate loops want >= 5x the ~55 ms motor lag's bandwidth, and the
# gear springs of the F450 model stay stable; 250 Hz (PX4 SITL's rate) costs 20 % more CPU for no visible gain.
PHYSICS_RATE_HZ = 200.0
SETTLED_M_S = 0.1


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
        if len(self.vehicles) > 1:
            self._check_midair()

    def _check_midair(self) -> None:
        """Vehicles that touch each other both crash (frozen vehicles still count as obstacles)."""
        fleet = list(self.vehicles.values())
        for i, a in enumerate(fleet):
            for b in fleet[i + 1 :]:
                ta, tb = a.truth, b.truth
                if not World.vehicles_touch(ta.pos_ned_m, tb.pos_ned_m):
                    continue
                closing = math.dist(ta.vel_ned_m_s, tb.vel_ned_m_s)
                if ta.pos_ned_m[2] > -NEAR_GROUND_M and tb.pos_ned_m[2] > -NEAR_GROUND_M and closing < 0.1:
                    continue  # parked side by side on the ground
                a.crash(f"collision with vehicle {b.sysid} at {closing:.1f} m/s")
                b.crash(f"collision with vehicle {a.sysid} at {closing:.1f} m/s")

    def run_until(self, t_s: float, on_step: Callable[[Simulation], object] | None = None) -> None:
        """Step until simulated time reaches ``t_s``; ``on_step`` is called after every step."""
        end = round(t_s / self.dt_s)
        while self._steps < end:
            self.step()
            if on_step is not None:
                on_step(self)

    def run_for(self, duration_s: float, on_step: Callable[[Simulation], object] | None = None) -> None:
        self.run_until(self.t_s + duration_s, on_step)

    def take_off(self, altitude_m: float | None = None, timeout_s: float = 30.0) -> None:
        """Arm every vehicle, take off (default MIS_TAKEOFF_ALT) and run until all hold.

        For headless runs (offline evaluation, benchmarks) that need vehicles in the
        air without a ground station; returns once every vehicle is in Hold and
        moving slower than ``SETTLED_M_S`` on each axis. Raises ``RuntimeError`` naming the vehicle
        and PX4's reason if one refuses, ``TimeoutError`` if one never settles.
        """
        for sysid, v in self.vehicles.items():
            for outcome in (v.arm(), v.takeoff(altitude_m)):
                if not outcome.ok:
                    raise RuntimeError(f"vehicle {sysid}: {outcome.reason}")
        deadline = self.t_s + timeout_s

        def settled(v: Vehicle) -> bool:
            # PX4 switches to Hold 0.3 m short of the target; wait until the climb has died out too.
            return v.mode == FlightMode.HOLD and max(abs(c) for c in v.estimate.vel_ned_m_s) < SETTLED_M_S

        while not all(settled(v) for v in self.vehicles.values()):
            if self.t_s >= deadline:
                late = [s for s, v in self.vehicles.items() if not settled(v)]
                raise TimeoutError(f"vehicles {late} not holding still after {timeout_s:g} s")
            self.run_for(0.1)

    def vehicle(self, sysid: int) -> Vehicle:
        return self.vehicles[sysid]

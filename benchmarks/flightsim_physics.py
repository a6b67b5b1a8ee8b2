"""Real-time factor of one flightsim vehicle stepping as fast as it can.

Prints, for the same machine and run:

- the pure JSBSim F450 baseline: ``fdm.run()`` with four constant motor
  commands, nothing else;
- the full vehicle: physics + commander/navigator + position, attitude and
  rate control + mixer + collision checks + every sensor of the scenario +
  the state estimate, hovering after a takeoff;

and the ratio of the two (how much of the budget our Python autopilot takes).
MAVLink packing is not included (that is the runner's benchmark). It also
prints the flight-quality figures from the same hover (truth, still air):
takeoff altitude error and the position standard deviation per axis.

    .venv/bin/python benchmarks/flightsim_physics.py [--seconds 60] [--scenario wall_hover]
"""

from __future__ import annotations

import argparse
import statistics
import time

from flightsim.physics import F450Physics
from flightsim.simulation import Simulation
from secuav_common.scenario import Home, load_scenario


def jsbsim_baseline(sim_seconds: float, dt_s: float) -> float:
    """Simulated seconds per wall-clock second of bare JSBSim stepping."""
    phys = F450Physics(Home(), (0.0, 0.0, 0.0), 0.0, dt_s)
    phys.set_motors((0.41, 0.41, 0.41, 0.41))
    fdm = phys._fdm  # bare stepping: no state read-out, as the baseline must be
    steps = round(sim_seconds / dt_s)
    t0 = time.perf_counter()
    for _ in range(steps):
        fdm.run()
    return sim_seconds / (time.perf_counter() - t0)


def full_vehicle(scenario: str, sim_seconds: float) -> tuple[float, float, float, tuple[float, float, float]]:
    """(real-time factor, us per physics step, takeoff error m, hover std per NED axis m)."""
    sim = Simulation(load_scenario(scenario))
    v = next(iter(sim.vehicles.values()))
    sim.run_for(0.2)
    v.arm()
    v.takeoff()
    sim.run_for(8.0)  # airborne and holding: the whole cascade runs from here on
    takeoff_error = abs(-v.truth.pos_ned_m[2] - v.get_param("MIS_TAKEOFF_ALT").value)  # type: ignore[union-attr]
    track: list[tuple[float, float, float]] = []

    def each_step(_s: Simulation) -> None:
        v.pop_readings()
        v.pop_gps()
        track.append(v.truth.pos_ned_m)

    t0 = time.perf_counter()
    sim.run_for(sim_seconds, each_step)
    wall = time.perf_counter() - t0
    std = tuple(statistics.pstdev(p[i] for p in track) for i in range(3))
    return sim_seconds / wall, wall / round(sim_seconds / sim.dt_s) * 1e6, takeoff_error, std  # type: ignore[return-value]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per measurement")
    parser.add_argument("--scenario", default="wall_hover")
    args = parser.parse_args()
    dt_s = Simulation(load_scenario(args.scenario)).dt_s
    base = jsbsim_baseline(args.seconds, dt_s)
    rtf, us_per_step, takeoff_error, std = full_vehicle(args.scenario, args.seconds)
    print(f"physics rate            : {1 / dt_s:.0f} Hz")
    print(f"JSBSim alone            : {base:8.1f} x real time ({1e6 * dt_s / base:.1f} us/step)")
    print(f"vehicle ({args.scenario})".ljust(24) + f": {rtf:8.1f} x real time ({us_per_step:.1f} us/step)")
    print(f"vehicle / JSBSim        : {rtf / base:8.3f}")
    print(f"takeoff altitude error  : {takeoff_error:.3f} m (truth, MIS_TAKEOFF_ALT)")
    print(f"hover std N/E/D         : {std[0]:.3f} / {std[1]:.3f} / {std[2]:.3f} m (truth, still air)")


if __name__ == "__main__":
    main()

"""What the simulator costs with its MAVLink link: real-time factor and CPU per vehicle.

Prints, measured in the same run on this machine:

1. Real-time factor of one hovering vehicle in as-fast-as-possible mode
   (``--speed 0``) through the real runner: physics, autopilot, sensors, and
   every MAVLink frame packed and sent over UDP on 127.0.0.1, against the
   baseline of the same flight stepped without the MAVLink side. Target: at
   least 50x.
2. CPU used by 1, 4 and 16 hovering vehicles at 1x wall clock: each count runs
   in a fresh child process (the same runner as ``secuav-sim``); after the
   takeoff the child's CPU time (user + system) over ``--window`` wall seconds
   is divided by the window. 1.00 = one core. Target: 16 vehicles within one
   core. The scenarios are generated: a 3 m grid among the eight anchors of
   ``formation.yaml``, each vehicle with a downward laser, the eight UWB ranges,
   GPS and one inter-vehicle range to its neighbour.

    .venv/bin/python benchmarks/flightsim_bench.py [--seconds 60] [--window 20] [--counts 1,4,16]

CPU and wall figures are shared with whatever else runs on the machine: run
it on a quiet machine, or read the ratios rather than the absolute numbers.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import time

from flightsim.runner import RunConfig, SimRunner
from flightsim.simulation import Simulation
from secuav_common.loading import validate
from secuav_common.scenario import Scenario, load_scenario
from secuav_common.urls import Endpoint

TAKEOFF_S = 6.0  # sim seconds to get every vehicle into a settled hover before measuring


def grid_scenario(n: int) -> Scenario:
    """``n`` vehicles on a 3 m grid, sensors as in formation.yaml, each ranging to one neighbour."""
    base = load_scenario("formation").model_dump(mode="json")
    template = base["vehicles"][0]
    side = max(1, round(n**0.5 + 0.499))
    vehicles = []
    for i in range(n):
        sysid = i + 1
        row, col = divmod(i, side)
        v = json.loads(json.dumps(template))
        v.update(sysid=sysid, name=f"uav{sysid}", target=None)
        v["start"] = {"pos_ned_m": [1.0 + 3.0 * row, 1.0 + 3.0 * col, 0.0], "yaw_deg": 0.0}
        if n > 1:
            v["sensors"]["inter_vehicle"]["peers"] = [sysid % n + 1]
        else:
            v["sensors"]["inter_vehicle"] = None
        vehicles.append(v)
    base.update(name=f"grid{n}", vehicles=vehicles)
    return validate(Scenario, base, f"<grid of {n}>")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _take_off(sim: Simulation) -> None:
    sim.run_for(0.2)
    for v in sim.vehicles.values():
        assert v.arm().ok and v.takeoff().ok
    sim.run_for(TAKEOFF_S)


def baseline_rtf(sim_seconds: float) -> float:
    """Same vehicle, same flight, no MAVLink: simulated seconds per wall second."""
    sim = Simulation(load_scenario("wall_hover"))
    v = sim.vehicles[1]
    _take_off(sim)

    def drain(_s: Simulation) -> None:  # the runner's link pops these; do the same here
        v.pop_readings()
        v.pop_gps()
        v.pop_status_texts()

    t0 = time.perf_counter()
    sim.run_for(sim_seconds, drain)
    return sim_seconds / (time.perf_counter() - t0)


async def _runner_rtf(sim_seconds: float) -> tuple[float, int]:
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a listener, so sends are real deliveries
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    port = sink.getsockname()[1]
    cfg = RunConfig(load_scenario("wall_hover"), [Endpoint("udpout", "127.0.0.1", port)], speed=0.0)
    try:
        async with SimRunner(cfg) as runner:
            _take_off(runner.sim)
            v = runner.sim.vehicles[1]
            v.pop_readings()  # readings of the takeoff are not part of the measured stream
            v.pop_gps()
            cfg.duration_s = runner.sim.t_s + sim_seconds
            drained = 0

            def drain() -> None:
                nonlocal drained
                while True:
                    try:
                        sink.recv(65536)
                    except BlockingIOError:
                        return
                    drained += 1

            asyncio.get_running_loop().add_reader(sink.fileno(), drain)
            summary = await runner.run(asyncio.Event())
            asyncio.get_running_loop().remove_reader(sink.fileno())
            return summary.real_time_factor, runner.vehicles[0].personality.stats.tx_frames
    finally:
        sink.close()


async def _hover_at_1x(n: int, window_s: float) -> dict[str, float]:
    """Child-process body: n vehicles hovering at 1x; CPU over ``window_s`` wall seconds."""
    scenario = grid_scenario(n)
    base_port = _free_udp_port()
    endpoints = [Endpoint("udpout", "127.0.0.1", base_port + i) for i in range(n)]
    stop = asyncio.Event()
    async with SimRunner(RunConfig(scenario, endpoints, speed=1.0)) as runner:
        sim = runner.sim
        sim.run_for(0.2)
        for v in sim.vehicles.values():
            assert v.arm().ok and v.takeoff().ok
        task = asyncio.create_task(runner.run(stop))
        await asyncio.sleep(TAKEOFF_S)
        cpu0, wall0, sim0 = time.process_time(), time.monotonic(), sim.t_s
        frames0 = sum(v.personality.stats.tx_frames for v in runner.vehicles)
        await asyncio.sleep(window_s)
        cpu, wall, sim_dt = time.process_time() - cpu0, time.monotonic() - wall0, sim.t_s - sim0
        frames = sum(v.personality.stats.tx_frames for v in runner.vehicles) - frames0
        flying = sum(1 for v in sim.vehicles.values() if v.armed and not v.crashed and -v.truth.pos_ned_m[2] > 2.0)
        stop.set()
        await task
    return {"n": n, "cpu_cores": cpu / wall, "rtf": sim_dt / wall, "frames_per_s": frames / wall, "flying": flying}


def cpu_at_1x(n: int, window_s: float) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(n), "--window", str(window_s)],
        check=True,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds for the real-time factor")
    parser.add_argument("--window", type=float, default=20.0, help="wall seconds of CPU measurement per count")
    parser.add_argument("--counts", default="1,4,16", help="vehicle counts for the CPU measurement")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(asyncio.run(_hover_at_1x(args.child, args.window))))
        return

    base = baseline_rtf(args.seconds)
    rtf, frames = asyncio.run(_runner_rtf(args.seconds))
    print(f"1 vehicle, as fast as possible, {args.seconds:g} s simulated (hovering):")
    print(f"  without MAVLink (baseline)  : {base:7.1f} x real time")
    print(f"  with MAVLink over UDP       : {rtf:7.1f} x real time   (target >= 50x)")
    print(f"  MAVLink / baseline          : {rtf / base:7.3f}   ({frames / args.seconds:.0f} frames per sim second)")
    print(f"CPU at 1x wall clock, hovering, {args.window:g} s window per count (1.00 = one core):")
    one = None
    for n in (int(c) for c in args.counts.split(",")):
        r = cpu_at_1x(n, args.window)
        one = one if one is not None else r["cpu_cores"] / n
        print(
            f"  {n:3d} vehicles: {r['cpu_cores']:5.2f} cores  ({r['cpu_cores'] / n * 100:5.1f} % per vehicle,"
            f" x{r['cpu_cores'] / n / one:4.2f} of the first count's per-vehicle cost), rtf {r['rtf']:.2f},"
            f" {r['frames_per_s']:.0f} frames/s, {int(r['flying'])}/{n} hovering"
        )
    print("  target: 16 vehicles within one core")


if __name__ == "__main__":
    main()

"""How well ``secuav-study`` spreads offline cells over Dask workers, and what it costs per cell.

    .venv/bin/python benchmarks/study_bench.py [--cells 48] [--duration 20]

Measured in one run, on one machine, so the ratios compare like with like:
- baseline: the same cells through ``study.cells.run_cell`` in a plain loop (no Dask, no storage);
- ``secuav-study``'s runner on an embedded LocalCluster with 1 and with 2 workers, storage included.
Printed: cells/s of each, the scaling efficiency (rate with 2 workers / (2 x rate with 1)), and the
overhead per cell of the 1-worker run against the plain loop. Goals: efficiency >= 0.8 on 2 workers
(on a 2-core machine that is otherwise idle) and overhead <= 10 %.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from study.cells import run_cell
from study.runner import dask_client, run
from study.spec import expand, parse_study

STUDY = """
name: bench
scenario: anchors8
duration_s: {duration}
estimators: [ekf, secekf]
seeds: {seeds}
attacks:
  - none
  - profile: anchors-constant
    params: {{offset_m: [0.3, 1.5], start_s: 2.0}}
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", type=int, default=48, help="cells per measurement (a multiple of 3)")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of flight per cell")
    args = p.parse_args()
    study = parse_study(STUDY.format(duration=args.duration, seeds=max(1, args.cells // 3)), "<bench>")
    cells = expand(study, "<bench>")
    names = study.estimators
    run_cell(cells[0], names)  # warm imports and caches once, outside every measurement

    t0 = time.perf_counter()
    for cell in cells:
        run_cell(cell, names)
    loop_s = time.perf_counter() - t0

    rates = {}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as tmp, dask_client(workers, None) as client:
            client.submit(run_cell, cells[0], names, pure=False).result()  # workers import once, unmeasured
            t0 = time.perf_counter()
            summary = run(cells, names, Path(tmp), client, set(), progress=False)
            rates[workers] = summary.ran / (time.perf_counter() - t0)

    loop_rate = len(cells) / loop_s
    efficiency = rates[2] / (2 * rates[1])
    overhead = loop_rate / rates[1] - 1.0
    print(f"cells: {len(cells)} x {len(names)} estimators, {args.duration:g} s flights")
    print(f"plain loop (no Dask, no storage): {loop_rate:7.2f} cells/s  ({1000 * loop_s / len(cells):.0f} ms/cell)")
    print(f"secuav-study, 1 worker:           {rates[1]:7.2f} cells/s")
    print(f"secuav-study, 2 workers:          {rates[2]:7.2f} cells/s")
    print(f"scaling efficiency on 2 workers:  {efficiency:7.2f}   (goal >= 0.8)")
    print(f"overhead per cell vs plain loop:  {100 * overhead:6.1f} %  (goal <= 10 %)")


if __name__ == "__main__":
    main()

"""What a long-lived cluster pays after an estimator's code changed (docs/bench.md, "Long-lived workers").

    .venv/bin/python benchmarks/stale_workers_bench.py [--seeds 10]

A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 (free ports), and a plugin estimator
``mine`` (the example plugin's Huber with its own default, a distribution on PYTHONPATH found by its entry point).
One run of a small study, a one-line edit of ``mine``, the run again (every cell in the workers' child process
that loaded the new code), a third run (nothing left to do), then the same study on a new LocalCluster.
Printed: the wall time of each ``secuav-study run``, the ratio edited / first, and how many of the edited run's
rows equal the new cluster's (they must all).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent
MINE = '''from secuav_example_plugin.huber import Huber


class Mine(Huber):
    name = "mine"

    def __init__(self, model, *, huber_k: float = {k}, **params):
        super().__init__(model, huber_k=huber_k, **params)
'''
STUDY = """
name: stale
scenario: anchors6_small
duration_s: 6
legs: [moving]
estimators: [mine]
seeds: {seeds}
attacks: [none, {{profile: anchors-moving-bias}}]
"""


def plugin(site: Path, k: str) -> None:
    (site / "idplug").mkdir(parents=True, exist_ok=True)
    (site / "idplug" / "__init__.py").write_text("")
    (site / "idplug" / "mine.py").write_text(MINE.replace("{k}", k))
    info = site / "idplug-0.1.0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: idplug\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text("[secuav.estimators]\nmine = idplug.mine:Mine\n")


def study_run(args: list[str], env: dict[str, str]) -> tuple[float, dict]:
    t0 = time.perf_counter()
    done = subprocess.run([str(BIN / "secuav-study"), "run", *args, "--no-progress"], capture_output=True,
                          text=True, env=env, check=True)  # fmt: skip
    return time.perf_counter() - t0, json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    from distributed import Client

    from study.store import load

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    opts = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        plugin(tmp / "site", "1.345")
        env = {**os.environ, "PYTHONPATH": str(tmp / "site"), "PYTHONWARNINGS": "ignore::DeprecationWarning"}
        study = tmp / "stale.yaml"
        study.write_text(STUDY.format(seeds=opts.seeds))
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        address = f"tcp://127.0.0.1:{port}"
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
        procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                   "--no-dashboard"], **quiet)]  # fmt: skip
        try:
            for name in ("w1", "w2"):
                worker = [str(BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--name", name, "--nworkers",
                          "1", "--nthreads", "1", "--no-dashboard"]  # fmt: skip
                procs.append(subprocess.Popen(worker, **quiet))
            with Client(address, timeout="60s") as client:
                client.wait_for_workers(2, timeout=120)
            out = tmp / "out"
            times = {}
            for label, k in (("first", None), ("edited", "0.6"), ("again", None)):
                if k is not None:
                    plugin(tmp / "site", k)
                times[label], summary = study_run([str(study), "--out", str(out), "--scheduler", address], env)
                print(f"{label:<14} {times[label]:6.1f} s  {json.dumps(summary)}", flush=True)
        finally:
            for proc in reversed(procs):
                proc.send_signal(signal.SIGINT)
            for proc in reversed(procs):
                proc.wait(30)
        times["fresh"], summary = study_run([str(study), "--out", str(tmp / "fresh"), "--workers", "2"], env)
        print(f"{'new cluster':<14} {times['fresh']:6.1f} s  {json.dumps(summary)}")
        cols = ["rmse_m", "mean_error_m", "max_error_m", "valid_fraction", "estimator_code", "code_key"]
        mine = [load(d).query("estimator == 'mine'").set_index("cell").sort_index()[cols] for d in (out, tmp / "fresh")]
        same = int((mine[0] == mine[1]).all(axis=1).sum())
        print(f"edited / first: {times['edited'] / times['first']:.2f}; rows equal to the new cluster's: "
              f"{same} of {len(mine[1])}")  # fmt: skip


if __name__ == "__main__":
    main()

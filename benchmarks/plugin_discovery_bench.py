"""What plugin discovery costs at start-up: ``secuav-proxy --help`` and a proxy start, before and after.

"Before" is the tree at ``--before`` (default: the commit before plugin discovery came in), exported with
``git archive`` to a temporary directory; "after" is this working tree. Both run with this interpreter (so the
same installed dependencies, and the example plugin when installed), the tree under test first on
``PYTHONPATH`` (each run checks that the modules came from it). Each figure is the median of ``--runs``
fresh processes, run alternately so that the machine's load falls on both alike:

- ``help``: ``secuav-proxy --help`` to its exit;
- ``start ekf``: ``secuav-proxy --scenario anchors8 --secure ekf --broker none`` until it logs ``proxy.ready``;
- ``start huber`` (after only, when the example plugin is installed): the same with the plugin's estimator,
  found through its entry point.

The table gives the ratios after / before (1.00: discovery costs nothing measurable). Nothing here asserts a
time. The hot path (frames through the pipeline) does not touch discovery; ``benchmarks/proxy_bench.py
--quick`` measures it.

    .venv/bin/python benchmarks/plugin_discovery_bench.py [--runs 15] [--before REV]
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECK = "import mitm_proxy, sys; assert mitm_proxy.__file__.startswith(sys.argv[1]), mitm_proxy.__file__"
MAIN = "import sys; from mitm_proxy.cli import main; sys.argv[0] = 'secuav-proxy'; sys.exit(main(sys.argv[1:]))"


def _before_rev() -> str:
    cmd = ["git", "-C", str(ROOT), "log", "--diff-filter=A", "--format=%H", "--", "secuav_common/plugins.py"]
    added = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.split()
    return f"{added[-1]}^" if added else "HEAD"


def _export(rev: str, where: Path) -> Path:
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev], capture_output=True, check=True)
    with tarfile.open(fileobj=BytesIO(data.stdout)) as tar:
        tar.extractall(where, filter="data")
    return where


def _env(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}


def _free_udp() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def time_help(tree: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", MAIN, "--help"], env=_env(tree), cwd=tree, stdout=subprocess.DEVNULL,
                   check=True)  # fmt: skip
    return time.perf_counter() - t0


def time_start(tree: Path, secure: str) -> float:
    ports = ["--vehicle", f"udpin://127.0.0.1:{_free_udp()}", "--ground", f"udpout://127.0.0.1:{_free_udp()}"]
    argv = [sys.executable, "-c", MAIN, "--scenario", "anchors8", "--secure", secure, "--broker", "none", *ports]
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, env=_env(tree), cwd=tree, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)  # fmt: skip
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            if "proxy.ready" in line:
                return time.perf_counter() - t0
        raise RuntimeError(f"secuav-proxy exited {proc.wait()} before it was ready (secure {secure})")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(15)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=15)
    p.add_argument("--before", default=None, help="git revision of 'before' (default: before plugin discovery)")
    args = p.parse_args(argv)
    rev = args.before or _before_rev()
    from importlib import metadata

    try:
        metadata.distribution("secuav-example-plugin")
        plugin = True
    except metadata.PackageNotFoundError:
        plugin = False
    with tempfile.TemporaryDirectory(prefix="secuav-before-") as tmp:
        before = _export(rev, Path(tmp))
        trees = {"before": before, "after": ROOT}
        for tree in trees.values():
            subprocess.run([sys.executable, "-c", CHECK, str(tree)], env=_env(tree), cwd=tree, check=True)
        cases: list[tuple[str, str, object]] = [("help", name, time_help) for name in trees]
        cases += [("start ekf", name, lambda t: time_start(t, "ekf")) for name in trees]
        if plugin:
            cases.append(("start huber", "after", lambda t: time_start(t, "huber")))
        results: dict[tuple[str, str], list[float]] = {(c, n): [] for c, n, _ in cases}
        for _ in range(args.runs):
            for case, name, fn in cases:
                results[(case, name)].append(fn(trees[name]))  # type: ignore[operator]
    short = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], capture_output=True, text=True)
    print(f"before = {rev} ({short.stdout.strip()}), after = working tree; median of {args.runs} fresh processes each")
    print(f"{'case':<12} {'before [ms]':>12} {'after [ms]':>12} {'after/before':>13}")
    base = {c: statistics.median(results[(c, 'before')]) for c in ("help", "start ekf")}
    for (case, name), times in results.items():
        if name != "after":
            continue
        ref = base["start ekf" if case.startswith("start") else "help"]
        med = statistics.median(times)
        shown = f"{ref * 1e3:12.0f}" if case in base else f"{'(ekf)':>12}"
        print(f"{case:<12} {shown} {med * 1e3:12.0f} {med / ref:13.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

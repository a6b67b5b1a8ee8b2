"""Regenerate docs/measured.md from one run: proxy_bench on two streams, the fuzz, fleet and memo benches.

    nice .venv/bin/python benchmarks/measured.py [--quick] [--fuzz-datagrams 200000] [--soak-minutes 10]
        [--out docs/measured.md]

The page names what it came from (the commit, whether the tree had uncommitted changes, the machine, the
Python version, the mavlink-routerd build, the load when it started, the exact commands) and holds the
benches' printed output as it came, nothing else: rerun it on the same commit and you get the same page
but for the figures. mavlink-routerd is found as proxy_bench finds it (``MAVLINK_ROUTERD``, or
``build/mavlink-router`` from ``bash benchmarks/build_mavlink_router.sh``); without it its rows say so.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TLOG = "tests/data/ardupilot-copter-guided.tlog"
sys.path.insert(0, str(ROOT / "benchmarks"))

from proxy_bench import ROUTERD  # noqa: E402  (where proxy_bench finds the router)


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False).stdout.strip()


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _router() -> str:
    if not ROUTERD.is_file():
        return "not built (its rows say so)"
    out = subprocess.run([str(ROUTERD), "--version"], capture_output=True, text=True, check=False)
    said = (out.stdout or out.stderr).strip().splitlines()
    return f"`{ROUTERD.name}`, {said[0] if said else 'version unknown'}"


def _run(argv: list[str]) -> str:
    """Run a bench, echo its progress, return what it printed (stdout and stderr in order)."""
    print("$ " + " ".join(argv), file=sys.stderr, flush=True)
    done = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"measured.py: {' '.join(argv)} exited with {done.returncode}:\n{done.stderr[-2000:]}")
    return "\n".join(ln for ln in done.stdout.splitlines() if not ln.startswith("  measured ")).strip()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="proxy_bench --quick (shorter ladder, 5 s soak)")
    ap.add_argument("--soak-s", type=float, help="proxy_bench's RSS soak (default: its own)")
    ap.add_argument("--record-s", type=float, default=5.0, help="seconds of flightsim telemetry to record")
    ap.add_argument("--fuzz-datagrams", type=int, default=200_000, help="fuzz_bench datagrams (0: skip it)")
    ap.add_argument("--fleet-procs", default="1,2,4,8", help="fleet_bench process counts ('': skip it)")
    ap.add_argument("--memo-record-s", type=float, default=60.0,
                    help="memo_bench: seconds of flightsim telemetry for one pass (0: skip it)")
    ap.add_argument("--soak-minutes", type=float, default=0.0, help="soak_bench minutes (0: skip it)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs/measured.md")
    args = ap.parse_args()
    bench = ["benchmarks/proxy_bench.py", *(["--quick"] if args.quick else [])]
    if args.soak_s is not None:
        bench += ["--soak-s", f"{args.soak_s:g}"]
    started = dt.datetime.now(dt.UTC)
    commit = _git("rev-parse", "--short=12", "HEAD")  # what the benches ran (they import the tree as it is now)
    dirty = " (with uncommitted changes)" if _git("status", "--porcelain", "--untracked-files=no") else ""
    load = os.getloadavg()[0]
    runs = [
        ("ArduPilot SITL's recorded stream", [*bench, "--tlog", TLOG]),
        ("secuav-sim (flightsim) telemetry", [*bench, "--record-s", f"{args.record_s:g}"]),
    ]
    outputs = [(title, argv, _run(argv)) for title, argv in runs]
    fuzz = None
    if args.fuzz_datagrams:
        fuzz_argv = ["benchmarks/fuzz_bench.py", "--datagrams", str(args.fuzz_datagrams)]
        fuzz = (fuzz_argv, _run(fuzz_argv))
    fleet = None
    if args.fleet_procs:
        fleet_argv = ["benchmarks/fleet_bench.py", "--procs", args.fleet_procs, "--seconds", "2"]
        fleet = (fleet_argv, _run(fleet_argv))
    memo = None
    if args.memo_record_s:
        memo_argv = ["benchmarks/memo_bench.py", "--record-s", f"{args.memo_record_s:g}"]
        memo = (memo_argv, _run(memo_argv))
    soak = None
    if args.soak_minutes:
        soak_argv = ["benchmarks/soak_bench.py", "--minutes", f"{args.soak_minutes:g}"]
        soak = (soak_argv, _run(soak_argv))
    ended = _git("rev-parse", "--short=12", "HEAD")
    if ended != commit:
        dirty += f"; HEAD was `{ended}` when the run ended"
    lines = [
        "# Measured: forwarding speed and hostile input",
        "",
        "Generated by `benchmarks/measured.py` from one run; every figure below is that run's printed output.",
        "Rerun it to regenerate the page (`nice .venv/bin/python benchmarks/measured.py`). Nothing in the test",
        "suite asserts a time; each bench measures its baselines in the same run, so read the ratios.",
        "",
        f"- commit: `{commit}`{dirty}, branch `{_git('rev-parse', '--abbrev-ref', 'HEAD')}`",
        f"- run: {started:%Y-%m-%d %H:%M} UTC, load average {load:.2f} when it started"
        " (the machine is shared: absolute figures move with it)",
        f"- machine: {os.cpu_count()} cores, {_cpu()}, {platform.system()} {platform.release()}",
        f"- Python {platform.python_version()} ({sys.executable.replace(str(ROOT) + '/', '')})",
        f"- mavlink-router: {_router()}",
        "",
        "How to read the tables: `CPU us/f` is the relay's CPU time per frame forwarded while the bench offers",
        "its CPU rate (lower is better); `lossless f/s` the highest offered rate with no frame lost (bounded by",
        "the Python sender); `+p99 ms` the latency added at 2 000 frames/s over the direct path. Rows:",
        "`secuav-bypass-*` forward with the attack bypassed, `secuav-rewrite-*` rewrite about 10 % of the",
        "frames (the stream's DISTANCE_SENSOR), `*-python` on the pure-Python path, `*-2ground` with a second",
        "ground endpoint on a port nobody listens on (the default configuration's shape). The benches replay",
        "the same seconds of telemetry over and over, so the fast route's rewrite memory answers every repeated",
        "reading; how much of a rewrite stays in C on one pass of a real stream is in \"Rewrites repeated in C\".",
    ]
    for title, argv, out in outputs:
        lines += ["", f"## {title}", "", f"`.venv/bin/python {' '.join(argv)}`", "", "```text", out, "```"]
    if fuzz is not None:
        argv, out = fuzz
        lines += ["", "## Hostile input", "", f"`.venv/bin/python {' '.join(argv)}` (half valid DISTANCE_SENSOR",
                  "frames, half random, mutated or oversized datagrams; see the script's doc):", "",
                  "```text", out, "```"]  # fmt: skip
    if fleet is not None:
        argv, out = fleet
        lines += ["", "## A fleet over several processes", "",
                  f"`.venv/bin/python {' '.join(argv)}` (one vehicle per process, bypass; docs/interfaces.md,",
                  '"Many vehicles, many cores"):', "", "```text", out, "```"]  # fmt: skip
    if memo is not None:
        argv, out = memo
        lines += ["", "## Rewrites repeated in C, one pass", "",
                  f"`.venv/bin/python {' '.join(argv)}` (each stream sent once through the proxy with the",
                  "rewrite profile above; mitm_proxy/README.md, \"The fast path\"):", "",
                  "```text", out, "```"]  # fmt: skip
    if soak is not None:
        argv, out = soak
        lines += ["", "## Soak", "", f"`.venv/bin/python {' '.join(argv)}` (a steady stream while the attack",
                  "profile is swapped every second; see the script's doc):", "", "```text", out, "```"]  # fmt: skip
    lines += ["", "## Not regenerated here", "",
              "Longer runs have their own scripts and are not part of this page's run:"
              + ("" if soak is not None else " the 10-minute soak (`benchmarks/soak_bench.py`),"),
              "per-endpoint rules (`benchmarks/routes_bench.py`), the web console",
              "(`benchmarks/console_bench.py`), plugin discovery (`benchmarks/plugin_discovery_bench.py`).",
              ""]  # fmt: skip
    args.out.write_text("\n".join(lines), encoding="utf-8")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

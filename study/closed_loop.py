"""Closed-loop cells: one real ``secuav-demo`` flight per estimator, on a port block of its own.

The demo flies the cell's scenario (``--scenario``, written as the client validated it): a demo's own, or
a plugin's or a file of a demo's shape (:func:`demos.catalog.demo_for`).

The demo starts its own embedded broker, simulator, proxy and MAVSDK
controllers, so several cells fly at once on one machine (each on a free block
of loopback ports) and on other machines alike. Metrics are the demo report's:
error from ground truth (distance to the wall, position, or inter-vehicle
range), whether it collided, and the sensors the secure stage flagged.
"""

from __future__ import annotations

import json
import random
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

from demos.catalog import PORT_SPAN, demo_for
from study.spec import SECURE_OFF, Cell

PORT_RANGE = (20_000, 40_000)


def _block_free(base: int) -> bool:
    socks = []
    try:
        for port in range(base, base + PORT_SPAN):
            for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
                s = socket.socket(socket.AF_INET, kind)
                socks.append(s)
                s.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        for s in socks:
            s.close()


def free_port_block(rng: random.Random | None = None) -> int:
    """A base port whose whole block is free on loopback now (blocks are drawn at random, so workers rarely meet)."""
    rng = rng or random.Random()
    for _ in range(200):
        base = rng.randrange(PORT_RANGE[0], PORT_RANGE[1] - PORT_SPAN, PORT_SPAN)
        if _block_free(base):
            return base
    raise RuntimeError(f"no free block of {PORT_SPAN} loopback ports in {PORT_RANGE}")


def _demo_command() -> list[str]:
    exe = Path(sys.executable).parent / "secuav-demo"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "demos"]


def _attack_args(cell: Cell, workdir: Path) -> list[str]:
    if cell.profile is None:
        return ["--attack", "none"]
    if cell.attack_ref is not None and not Path(cell.attack_ref).exists():  # a library profile, by name
        args = ["--attack", cell.attack_ref]
        for key, value in cell.params.items():
            args += ["--param", f"{key}={json.dumps(value)}"]
        return args
    # A profile file may not exist on this worker: fly the resolved profile the client validated.
    path = workdir / "profile.yaml"
    path.write_text(yaml.safe_dump(cell.profile.model_dump(mode="json"), sort_keys=False), encoding="utf-8")
    return ["--attack", str(path)]


def figures_from_report(demo: str, case: dict[str, Any]) -> dict[str, Any]:
    """A study row's figures from one case of a demo's report.json."""
    if demo == "wall-hover":
        err, flagged = case["distance_error_m"], case["flagged_by_proxy"]
    elif demo == "localise":
        err, flagged = case["position_error_m"], case["flagged_by_proxy"]
    else:
        err, flagged = case["range_error_m"], case["uav2"]["flagged_by_proxy"]
    steps = case.get("secure_step_time_us") or {}
    return {
        "rmse_m": err.get("rms"),
        "max_error_m": err.get("max"),
        "collided": bool(case.get("collided")),
        "min_distance_m": case.get("min_distance_m"),
        "flagged": flagged,
        "step_time_us_median": steps.get("median"),
        "step_time_us_p99": steps.get("p99"),
    }


def _scenario_args(cell: Cell, workdir: Path) -> list[str]:
    """The cell's scenario as the client validated it, as a file: a plugin's or a file's flies as the demos' own."""
    path = workdir / "scenario.yaml"
    path.write_text(yaml.safe_dump(cell.scenario.model_dump(mode="json"), sort_keys=False), encoding="utf-8")
    return ["--scenario", str(path)]


def fly_one(cell: Cell, estimator: str, workdir: Path) -> dict[str, Any]:
    demo = demo_for(cell.scenario)
    out = workdir / estimator
    secure = SECURE_OFF if estimator == SECURE_OFF else estimator
    argv = [
        *_demo_command(), demo, *_scenario_args(cell, workdir), *_attack_args(cell, workdir), "--secure", secure,
        "--seconds", str(cell.duration_s), "--settle", str(cell.settle_s), "--seed", str(cell.seed),
        "--out", str(out), "--base-port", str(free_port_block()),
    ]  # fmt: skip
    timeout_s = 240.0 + 2.0 * (cell.duration_s + cell.settle_s)
    done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s, check=False)
    if done.returncode != 0:
        tail = " / ".join((done.stderr or done.stdout).strip().splitlines()[-3:])
        raise RuntimeError(f"secuav-demo {demo} exited {done.returncode}: {tail}")
    report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    (case,) = report["cases"].values()
    return figures_from_report(demo, case)


def run_closed_loop(cell: Cell, names: list[str]) -> dict[str, dict[str, Any]]:
    """One flight per estimator; a flight that fails is that estimator's error, the others still fly."""
    out: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix=f"secuav-study-{cell.key}-") as tmp:
        for name in names:
            try:
                out[name] = fly_one(cell, name, Path(tmp))
            except (RuntimeError, ValueError, OSError, subprocess.TimeoutExpired, KeyError) as exc:
                out[name] = {"error": f"{type(exc).__name__}: {exc}"}
    return out

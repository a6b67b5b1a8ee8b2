"""The wall-hover demo (seed Fig. A.5): hold 2.5 m from a wall on five forward range sensors.

One *case* is one flight: broker, simulator, proxy and the MAVSDK controller of
``examples/wall_hover_controller.py``. The controller takes off and holds; after
``settle_s`` the demo pushes the attack profile over MQTT (exactly what
``secuav-attack apply`` does) and scores the rest of the hold from the
simulator's ground truth (``secuav/v1/truth``), never from what the controller
believed.
"""

from __future__ import annotations

import asyncio
import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from demos.mqtt_tap import Tap
from demos.scoring import Window, distance_metrics
from demos.stack import Ports, Processes, tool
from secuav_common.broker import EmbeddedBroker
from secuav_common.scenario import Scenario, load_scenario

log = logging.getLogger(__name__)
CONTROLLER = "demos.controllers.wall_hover"  # also examples/wall_hover_controller.py
SYSID = 1


@dataclass(frozen=True, slots=True)
class Case:
    attack: str | None  # library name or profile file; None = no attack
    secure: str  # estimator name, or "off"

    @property
    def slug(self) -> str:
        return f"attack-{'on' if self.attack else 'off'}_secure-{'off' if self.secure == 'off' else 'on'}"


@dataclass(frozen=True, slots=True)
class Options:
    out: Path
    scenario: str = "wall_hover"
    seconds: float = 40.0  # hold time, of which the first settle_s is not scored
    settle_s: float = 5.0
    seed: int | None = None
    ports: Ports = field(default_factory=Ports)
    attack_params: dict[str, Any] | None = None


def attack_payload(attack: str, params: dict[str, Any] | None) -> dict[str, Any]:
    """What goes on ``secuav/v1/attack/set``: a library name, or the content of a profile file."""
    path = Path(attack)
    if path.suffix in (".yaml", ".yml", ".json") or path.exists():
        import yaml

        return dict(yaml.safe_load(path.read_text(encoding="utf-8")))
    # The demo applies the profile when the scored window opens, so it starts at once.
    return {"library": attack, "parameters": {"start_s": 0.0, **(params or {})}}


async def _wait_for_event(path: Path, event: str, procs: Processes, timeout_s: float) -> float:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        procs.check_alive()
        controller = procs.running.get("controller")
        if path.exists():
            for line in path.read_text(encoding="utf-8").splitlines():
                entry = json.loads(line)
                if entry.get("kind") == "event" and entry.get("event") == event:
                    return float(entry["wall_s"])
        if controller is not None and controller.returncode is not None:
            code = controller.returncode
            raise RuntimeError(f"controller exited ({code}) before {event!r}: see {path.parent}/controller.log")
        await asyncio.sleep(0.2)
    raise TimeoutError(f"controller did not reach {event!r} within {timeout_s:.0f} s: see {path.parent}/controller.log")


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


async def run_case(case: Case, opts: Options, scenario: Scenario) -> dict[str, Any]:
    """Fly one case and return its figures; raw material stays in ``out/<slug>/``."""
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    p = opts.ports
    controller_log = out / "controller.jsonl"
    controller_log.unlink(missing_ok=True)
    topics = [f"secuav/v{SYSID}/{t}" for t in ("truth", "estimate", "attack/state", "secure/state", "stats")]
    seed = [] if opts.seed is None else ["--seed", str(opts.seed)]
    async with EmbeddedBroker(port=p.mqtt), Tap("127.0.0.1", p.mqtt, topics) as tap, Processes(out) as procs:
        await procs.start("proxy", [
            tool("secuav-proxy"), "--scenario", opts.scenario,
            "--vehicle", f"udpin://127.0.0.1:{p.proxy_vehicle}",
            "--ground", f"udpout://127.0.0.1:{p.api}", "--ground", f"udpout://127.0.0.1:{p.gcs}",
            "--secure", case.secure, "--broker", p.broker_url, "--record", str(out / "record"),
        ])  # fmt: skip
        await procs.start("sim", [
            tool("secuav-sim"), opts.scenario, "--mavlink", f"udpout://127.0.0.1:{p.proxy_vehicle}",
            "--broker", p.broker_url, "--truth-csv", str(out / "truth.csv"), *seed,
        ])  # fmt: skip
        await procs.start("controller", [
            sys.executable, "-m", CONTROLLER, "--url", f"udpin://127.0.0.1:{p.api}",
            "--seconds", str(opts.seconds), "--log", str(controller_log),
        ])  # fmt: skip
        t_hold = await _wait_for_event(controller_log, "holding", procs, timeout_s=90.0)
        await asyncio.sleep(opts.settle_s)
        t_scored = time.time()
        ack: dict[str, Any] | None = None
        if case.attack is not None:
            payload = attack_payload(case.attack, opts.attack_params)
            ack = await tap.request(f"secuav/v{SYSID}/attack/set", payload, f"secuav/v{SYSID}/attack/state")
            if not ack.get("ok"):
                raise RuntimeError(f"the proxy rejected attack {case.attack!r}: {ack.get('error')}")
        t_landing = await _wait_for_event(controller_log, "landing", procs, timeout_s=opts.seconds + 60.0)
        await _wait_for_event(controller_log, "done", procs, timeout_s=60.0)
        truth = [(s.wall_s, s.payload) for s in tap.on(f"secuav/v{SYSID}/truth")]
        estimates = [(s.wall_s, s.payload) for s in tap.on(f"secuav/v{SYSID}/estimate")]
    window = Window(start_s=t_scored, end_s=t_landing, hold_s=t_hold)
    steps = [e for e in _read_jsonl(controller_log) if e.get("kind") == "step"]
    figures = distance_metrics(scenario, truth, steps, estimates, window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=ack)
    (out / "truth.jsonl").write_text("".join(json.dumps({"wall_s": t, **d}) + "\n" for t, d in truth), encoding="utf-8")
    (out / "estimates.jsonl").write_text(
        "".join(json.dumps({"wall_s": t, **d}) + "\n" for t, d in estimates), encoding="utf-8"
    )
    return figures


def cases(attack: str | None, secure: str, matrix: bool) -> list[Case]:
    if not matrix:
        return [Case(attack, secure)]
    on = secure if secure != "off" else DEFAULT_SECURE
    hit = attack if attack is not None else DEFAULT_ATTACK
    return [Case(None, "off"), Case(hit, "off"), Case(None, on), Case(hit, on)]


DEFAULT_ATTACK = "wall-spoof-two"
DEFAULT_SECURE = "recap"


async def run(selected: list[Case], opts: Options, progress: Any = print) -> list[dict[str, Any]]:
    scenario = load_scenario(opts.scenario)
    results = []
    for i, case in enumerate(selected, 1):
        progress(f"[{i}/{len(selected)}] wall-hover {case.slug} (attack {case.attack or 'none'}, secure {case.secure})")
        figures = await run_case(case, opts, scenario)
        err = figures["distance_error_m"]
        progress(
            f"    distance error rms {err['rms']:.2f} m, max {err['max']:.2f} m, "
            f"min distance {figures['min_distance_m']:.2f} m, collided {figures['collided']}"
        )
        results.append(figures)
    return results

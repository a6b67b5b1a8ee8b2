#!/usr/bin/env python3
"""The wall-hover demo's four-case matrix flown against ArduCopter SITL, as height hold over ground.

Not in CI: it needs the SITL binary (scripts/sitl/ardupilot.sh build). ArduPilot's SITL simulates
no wall, and all its rangefinders read along one direction (docs/ardupilot.md), so the wall is the
ground: ``scenarios/ardupilot_height.yaml`` gives the proxy's secure stage the three downward
rangefinders of scripts/sitl/rangefinders.parm as the redundant group, and the controller
(``demos/controllers/height_hold.py``, pymavlink, GUIDED velocity targets) holds 5 m on the mean
of the readings it is not told are attacked. Each case (attack off/on x secure off/on) boots a
fresh SITL and runs, as ``secuav-demo`` does: an embedded broker, ``secuav-proxy --record`` dialling
SITL's tcp port, the controller on the proxy's ground side, the attack pushed over MQTT
(``secuav/v1/attack/set``) ``--settle`` seconds into the hold, and the rest of the hold scored.

Ground truth is SITL's own, never the controller's belief: SIM_STATE (#108, the simulated
vehicle's true altitude), asked for at 20 Hz on SITL's second serial port (tcp 5762+10*I), which
the proxy does not carry; the height above ground is its altitude less the altitude it had on
the ground before arming. Output as ``secuav-demo``'s: ``<out>/report.json``, one folder per case
(the controller's log, truth, estimates, the proxy's recording and logs) and
``<out>/ardupilot_height_hold.png``.

    .venv/bin/python scripts/sitl/height_hold_matrix.py --out out/ardupilot-height-hold
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import statistics
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # run from a checkout: the repository's demos/, not an installed copy

from demos.flight import Case, attack_payload, read_jsonl, wait_for_event  # noqa: E402
from demos.mqtt_tap import Tap  # noqa: E402
from demos.report import plot, write_report  # noqa: E402
from demos.scoring import Window, height_metrics  # noqa: E402
from demos.stack import Processes, tool  # noqa: E402
from secuav_common.broker import EmbeddedBroker  # noqa: E402
from secuav_common.controlplane.topics import vehicle_topic  # noqa: E402
from secuav_common.scenario import load_scenario  # noqa: E402

DEMO = "ardupilot-height-hold"
SCENARIO = "ardupilot_height"
CONTROLLER = "demos.controllers.height_hold"
DEFAULT_ATTACK = "height-spoof-one"
DEFAULT_SECURE = "secekf"
SITL_SH = ROOT / "scripts" / "sitl" / "ardupilot.sh"
SIM_STATE_HZ = 20.0
SYSID = 1


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Truth:
    """SIM_STATE from SITL's second serial port, stamped on arrival (wall time), in a reader thread."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.samples: list[tuple[float, float]] = []  # (wall s, altitude AMSL m)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="truth", daemon=True)
        self.error: str | None = None

    def start(self) -> Truth:
        self._thread.start()
        return self

    def _connect(self) -> Any:
        end = time.monotonic() + 60.0
        while not self._stop.is_set():
            try:
                return mavutil.mavlink_connection(f"tcp:127.0.0.1:{self.port}", source_system=254,
                                                  dialect="ardupilotmega", retries=0)  # fmt: skip
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.5)
        return None

    def _run(self) -> None:
        try:
            conn = self._connect()
        except OSError as exc:
            self.error = f"no SITL on tcp {self.port}: {exc}"
            return
        if conn is None:
            return
        m = mavutil.mavlink
        asked = 0.0
        while not self._stop.is_set():
            if not self.samples and time.monotonic() - asked > 2.0:  # again until it comes (SITL may still boot)
                conn.mav.command_long_send(SYSID, 1, m.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                           m.MAVLINK_MSG_ID_SIM_STATE, 1e6 / SIM_STATE_HZ, 0, 0, 0, 0, 0)  # fmt: skip
                asked = time.monotonic()
            msg = conn.recv_match(type="SIM_STATE", blocking=True, timeout=0.5)
            if msg is not None:
                self.samples.append((time.time(), float(msg.alt)))
        conn.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def heights(self, ground_before_s: float) -> tuple[list[tuple[float, float]], float]:
        """(wall s, true height above ground) and the ground's altitude: the median before ``ground_before_s``."""
        before = [a for t, a in self.samples if t < ground_before_s] or [a for _, a in self.samples[:20]]
        ground = statistics.median(before)
        return [(t, a - ground) for t, a in self.samples], ground


class Sitl:
    """``scripts/sitl/ardupilot.sh run 1`` in its own process group, ended with SIGTERM to the group (SIGINT may be
    ignored in a background job, and the script's trap then never runs)."""

    def __init__(self, out: Path, instance: int, speedup: float) -> None:
        self.out, self.instance, self.speedup = out, instance, speedup
        self.proc: asyncio.subprocess.Process | None = None

    async def __aenter__(self) -> Sitl:
        env = {**os.environ, "SITL_INSTANCE": str(self.instance), "SITL_SPEEDUP": str(self.speedup)}
        with open(self.out / "sitl-run.log", "wb") as sink:
            self.proc = await asyncio.create_subprocess_exec(
                "nice", "-n", "10", "bash", str(SITL_SH), "run", "1", stdout=sink, stderr=asyncio.subprocess.STDOUT,
                env=env, start_new_session=True,
            )  # fmt: skip
        return self

    async def __aexit__(self, *exc: object) -> None:
        proc = self.proc
        if proc is None or proc.returncode is not None:
            return
        for sig, wait_s in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(proc.wait(), wait_s)
                return


async def wait_for_text(path: Path, text: str, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors="replace"):
            return True
        await asyncio.sleep(0.5)
    return False


async def fly(case: Case, args: argparse.Namespace, cache: Path) -> dict[str, Any]:
    out = args.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    log = out / "controller1.jsonl"
    log.unlink(missing_ok=True)
    api, mqtt = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    port = 5760 + 10 * args.instance
    sitl_log = cache / "run" / str(args.instance) / "sitl.log"
    sitl_log.unlink(missing_ok=True)  # a stale one would satisfy the wait below
    topics = [vehicle_topic(SYSID, "estimate"), vehicle_topic(SYSID, "attack", "state")]
    truth = Truth(port + 2)
    ack: dict[str, Any] | None = None
    async with (
        Sitl(out, args.instance, args.speedup),
        EmbeddedBroker(port=mqtt),
        Tap("127.0.0.1", mqtt, topics) as tap,
        Processes(out) as procs,
    ):
        if not await wait_for_text(sitl_log, "Waiting for connection", 60.0):
            raise RuntimeError(f"SITL did not open tcp {port}: see {sitl_log}")
        await procs.start("proxy", [
            tool("secuav-proxy"), "--scenario", SCENARIO, "--secure", case.secure, "--broker", f"mqtt://127.0.0.1:{mqtt}",
            "--record", str(out / "record"), "--vehicle", f"tcp://127.0.0.1:{port}",
            "--ground", f"udpout://127.0.0.1:{api}", "--stats-interval", "5",
        ])  # fmt: skip
        truth.start()
        await procs.start("controller1", [
            sys.executable, "-m", CONTROLLER, "--url", f"udpin://127.0.0.1:{api}", "--seconds", str(args.seconds),
            "--log", str(log), "--altitude", str(args.target), "--target", str(args.target),
        ])  # fmt: skip
        try:
            hold_s = await wait_for_event(log, "holding", procs, "controller1", 300.0)
            await asyncio.sleep(args.settle)
            t_scored = time.time()
            if case.attack is not None:
                ack = await tap.request(vehicle_topic(SYSID, "attack", "set"), attack_payload(case.attack, args.params))
                if not ack.get("ok"):
                    raise RuntimeError(f"the proxy rejected attack {case.attack!r}: {ack.get('error')}")
            landing = await wait_for_event(log, "landing", procs, "controller1", args.seconds + 60.0)
            await wait_for_event(log, "done", procs, "controller1", 120.0)
        finally:
            truth.stop()
        estimates = [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(SYSID, "estimate"))]
    if truth.error:
        raise RuntimeError(truth.error)
    entries = read_jsonl(log)
    armed_s = next((float(e["wall_s"]) for e in entries if e.get("event") == "armed"), t_scored)
    heights, ground = truth.heights(armed_s)
    (out / "truth1.jsonl").write_text("".join(json.dumps({"wall_s": t, "height_m": h}) + "\n" for t, h in heights),
                                      encoding="utf-8")  # fmt: skip
    (out / "estimates1.jsonl").write_text("".join(json.dumps({"wall_s": t, **e}) + "\n" for t, e in estimates),
                                          encoding="utf-8")  # fmt: skip
    window = Window(start_s=t_scored, end_s=landing, hold_s=hold_s)
    steps = [e for e in entries if e.get("kind") == "step"]
    figures = height_metrics(heights, args.target, steps, estimates, window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=ack,
                   ground_alt_m=round(ground, 3), truth_samples=len(heights))  # fmt: skip
    return figures


def summary(f: dict[str, Any]) -> str:
    err = f["distance_error_m"]
    return (f"height error rms {err['rms']:.2f} m, max {err['max']:.2f} m, min height {f['min_distance_m']:.2f} m, "
            f"touched ground {f['collided']}, flagged by proxy {f['flagged_by_proxy'] or 'none'}")  # fmt: skip


def cases(attack: str, secure: str) -> list[Case]:
    return [Case(None, "off"), Case(attack, "off"), Case(None, secure), Case(attack, secure)]


async def main_async(args: argparse.Namespace) -> int:
    cache = Path(os.environ.get("SECUAV_ARDUPILOT_CACHE", Path.home() / ".cache/secuav/ardupilot"))
    if not (cache / "latest" / "arducopter").exists() and "ARDUPILOT_BIN" not in os.environ:
        print(f"no SITL binary under {cache}/latest: run scripts/sitl/ardupilot.sh build SOURCE first")
        return 2
    version = {k: (cache / "latest" / k).read_text().strip() for k in ("version", "commit")
               if (cache / "latest" / k).exists()}  # fmt: skip
    print(f"ArduPilot: {version.get('version', '?')} built from {version.get('commit', '?')}; SITL instance "
          f"{args.instance} (tcp {5760 + 10 * args.instance}), speedup {args.speedup}", flush=True)  # fmt: skip
    selected = cases(args.attack, args.secure) if args.only is None else [cases(args.attack, args.secure)[args.only]]
    results = []
    for i, case in enumerate(selected, 1):
        print(f"[{i}/{len(selected)}] {DEMO} {case.slug} (attack {case.attack or 'none'}, secure {case.secure})",
              flush=True)  # fmt: skip
        figures = await fly(case, args, cache)
        print(f"    {summary(figures)}", flush=True)
        results.append(figures)
    settings = {"scenario": SCENARIO, "seconds": args.seconds, "settle_s": args.settle, "target_m": args.target,
                "attack_params": args.params, "cases": [[c.attack, c.secure] for c in selected],
                "ardupilot": version, "sitl_speedup": args.speedup, "command": " ".join(sys.argv)}  # fmt: skip
    print(f"report: {write_report(args.out, DEMO, settings, results)}\nplot:   {plot(args.out, DEMO, results)}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    from attack_profiles.resolve import parse_params

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attack", default=DEFAULT_ATTACK, help=f"library profile or file (default {DEFAULT_ATTACK})")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="attack parameter, repeatable")
    p.add_argument("--secure", default=DEFAULT_SECURE, help=f"estimator of the secure cases (default {DEFAULT_SECURE})")
    p.add_argument("--seconds", type=float, default=35.0, help="hold time per flight (default 35)")
    p.add_argument("--settle", type=float, default=5.0, help="seconds of hold before the attack and scoring")
    p.add_argument("--target", type=float, default=load_scenario(SCENARIO).vehicles[0].target.distance_m,
                   help="height to hold, metres (default: the scenario's)")  # fmt: skip
    p.add_argument("--instance", type=int, default=7, help="SITL instance: tcp 5760+10*I (default 7, out of the "
                   "way of scripts/sitl/ardupilot.sh run's 0)")  # fmt: skip
    p.add_argument("--speedup", type=float, default=1.0, help="SITL_SPEEDUP (default 1: real time)")
    p.add_argument("--only", type=int, choices=range(4), help="fly one case of the four (0-3, matrix order)")
    p.add_argument("--out", type=Path, default=Path("out") / DEMO)
    args = p.parse_args(argv)
    args.params = parse_params(args.param)
    try:
        return asyncio.run(main_async(args))
    except (RuntimeError, TimeoutError) as exc:
        print(f"height_hold_matrix: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

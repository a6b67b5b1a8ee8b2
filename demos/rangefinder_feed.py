"""The rangefinder-feed demo: the autopilot itself holds its altitude on a companion's rangefinders, and is lied to.

Issue 33's first vehicle-side demo (docs/ardupilot.md). The vehicle's height comes from three downward
rangefinders of a companion computer, DISTANCE_SENSOR ids 0, 1, 2 that ``secuav-feed`` computes from the
simulator's own truth and sends through ``secuav-proxy`` to the autopilot; the altitude hold runs ON THE
VEHICLE (ArduCopter GUIDED after take-off, or flightsim's Hold), the ground only takes off and lands
(``demos/controllers/vehicle_hold.py``, ``demos/controllers/onboard_hold.py``). The attack is an uplink
rule (``demos/profiles/vehicle-height-lie.yaml``: id 2 ramps to +3 m and stays); the secure stage sits on
the uplink (``--secure-direction uplink``) and substitutes its estimate in the frames the autopilot gets.

- ``--autopilot ardupilot``: ArduCopter SITL with ``demos/ardupilot/vehicle-rangefinders.parm``
  (``RNGFND1..3_TYPE 10``, ``EK3_SRC1_POSZ 2``); the feed and the score read SIM_STATE on SITL ports the
  proxy does not carry (SERIAL2, tcp 5763+10*I, and SERIAL1, tcp 5762+10*I). The proxy's layout is
  ``scenarios/ardupilot_height.yaml``'s group.
- ``--autopilot flightsim``: ``secuav-sim rangefinder_feed`` (three ``external`` downward lasers), the
  feed from its truth topic.

Why id 2: ArduPilot's MAVLink rangefinders take every DISTANCE_SENSOR of their orientation whatever its
id, so all three read the last frame of each burst (docs/vehicle-inputs.md), and flightsim fuses them in
id order, the last setting the height. The feed sends the three at one rate in id order, so id 2 is what
the autopilot flies by: one liar of three, which the secure stage can correct.

Scored from the simulator's truth: the true height's error from the target, touching the ground, and how
far the autopilot's own altitude (what it reports) sits from the truth (``own_minus_true_m``).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from demos.flight import Case, FlightProgress, Options, dump_jsonl, hold_and_attack, hold_on_sitl, read_jsonl
from demos.mqtt_tap import Tap
from demos.scoring import Window, _in, _rms_max, height_metrics, held_summary
from demos.sitl import Sitl, Truth, tcp_port
from demos.stack import Ports, Processes, tool
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.scenario import load_scenario

AUTOPILOTS = ("ardupilot", "flightsim")  # the first is the default
DEFAULT_ATTACK = str(Path(__file__).resolve().parent / "profiles" / "vehicle-height-lie.yaml")
DEFAULT_SECURE = "secekf"
SCENARIO = {"ardupilot": "ardupilot_height", "flightsim": "rangefinder_feed"}
VEHICLE_PARAMS = Path(__file__).resolve().parent / "ardupilot" / "vehicle-rangefinders.parm"
SYSID = 1
FEED_OFFSET = 9  # the feed's port: the proxy block's last (vehicle i's proxy port is B+i, one vehicle here)
BOOT_S = 60.0
ARMED_S = 300.0  # ArduPilot arms once its EKF has converged, 40-45 s after boot on a loaded machine
TAKEOFF_S = 120.0
CONNECT_S = 60.0  # the proxy imports its estimators (scipy) before it forwards: 20 s and more on a loaded machine


def feed_port(ports: Ports) -> int:
    return ports.proxy_vehicle + FEED_OFFSET


def _proxy_flags(case: Case, scenario: str, ports: Ports, out: Path) -> list[str]:
    secure = ["--secure", case.secure] + (["--secure-direction", "uplink"] if case.secure != "off" else [])
    return [tool("secuav-proxy"), "--scenario", scenario, *secure, "--broker", ports.broker_url,
            "--record", str(out / "record"), "--ground", f"udpout://127.0.0.1:{ports.api}",
            "--ground", f"udpout://127.0.0.1:{ports.gcs}", "--ground", f"udpin://127.0.0.1:{feed_port(ports)}",
            "--stats-interval", "5"]  # fmt: skip


async def _fly_ardupilot(case: Case, opts: Options, out: Path, log: Path, target_m: float) -> dict[str, Any]:
    assert opts.sitl is not None
    p, so = opts.ports, opts.sitl
    topics = [vehicle_topic(SYSID, "estimate"), vehicle_topic(SYSID, "attack", "state")]
    truth = Truth(tcp_port(so.instance, serial=1), SYSID)
    bar = FlightProgress(case.slug, opts.settle_s + opts.seconds, opts.progress)
    bar.phase("starting SITL, broker, proxy, feed")
    async with (
        bar,
        Sitl(so.binary, so.instance, SYSID, so.speedup, extra_params=[VEHICLE_PARAMS]) as sitl,
        EmbeddedBroker(port=p.mqtt),
        Tap("127.0.0.1", p.mqtt, topics) as tap,
        Processes(out) as procs,
    ):
        await sitl.ready(BOOT_S)
        await procs.start("proxy", [*_proxy_flags(case, SCENARIO["ardupilot"], p, out),
                                    "--vehicle", f"tcp://127.0.0.1:{tcp_port(so.instance)}"])  # fmt: skip
        truth.start()
        await sitl.serial_open(2)
        # SERIAL2 (tcp 5763+10*I): SITL's third port, SIM_STATE for the feed; SERIAL1 is the score's.
        await procs.start("feed", [
            tool("secuav-feed"), SCENARIO["ardupilot"], "--sensors", "rangefinders",
            "--to", f"udpout://127.0.0.1:{feed_port(p)}", "--truth", f"tcp://127.0.0.1:{tcp_port(so.instance) + 3}",
        ])  # fmt: skip
        await procs.start("controller1", [
            sys.executable, "-m", "demos.controllers.vehicle_hold", "--url", f"udpin://127.0.0.1:{p.api}",
            "--seconds", str(opts.seconds), "--log", str(log), "--altitude", str(target_m),
        ])  # fmt: skip
        flown = await hold_on_sitl(bar, tap, procs, log, case, opts, truth, SYSID, ARMED_S)
    window = Window(flown.t_scored, flown.landing, flown.hold_s)
    return _score(case, out, flown.heights, flown.entries, flown.estimates, window, target_m, flown.acks,
                  ground_alt_m=round(flown.ground_m, 3))  # fmt: skip


async def _fly_flightsim(case: Case, opts: Options, out: Path, log: Path, target_m: float) -> dict[str, Any]:
    p = opts.ports
    name = SCENARIO["flightsim"]
    topics = [vehicle_topic(SYSID, leaf, verb) for leaf, verb in
              (("truth", None), ("estimate", None), ("attack", "state"))]  # fmt: skip
    seed = [] if opts.seed is None else ["--seed", str(opts.seed)]
    bar = FlightProgress(case.slug, opts.settle_s + opts.seconds, opts.progress)
    async with bar, EmbeddedBroker(port=p.mqtt), Tap("127.0.0.1", p.mqtt, topics) as tap, Processes(out) as procs:
        await procs.start("proxy", [*_proxy_flags(case, name, p, out),
                                    "--vehicle", f"udpin://127.0.0.1:{p.proxy_vehicle}"])  # fmt: skip
        await procs.start("sim", [tool("secuav-sim"), name, "--mavlink", f"udpout://127.0.0.1:{p.proxy_vehicle}",
                                  "--broker", p.broker_url, "--truth-csv", str(out / "truth.csv"), *seed])  # fmt: skip
        await procs.start("feed", [tool("secuav-feed"), name, "--to", f"udpout://127.0.0.1:{feed_port(p)}",
                                   "--truth", p.broker_url, *seed])  # fmt: skip
        await procs.start("controller1", [
            sys.executable, "-m", "demos.controllers.onboard_hold", "--url", f"udpin://127.0.0.1:{p.api}",
            "--seconds", str(opts.seconds), "--log", str(log), "--altitude", str(target_m),
            "--connect-timeout", str(CONNECT_S),
        ])  # fmt: skip
        hold_s, t_scored, landing, acks = await hold_and_attack(bar, tap, procs, log, case, opts, SYSID, TAKEOFF_S)
        truth = [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(SYSID, "truth"))]
        estimates = [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(SYSID, "estimate"))]
    heights = [(t, -float(d["pos_ned_m"][2])) for t, d in truth]  # above flightsim's ground (z = 0 at home)
    return _score(case, out, heights, read_jsonl(log), estimates, Window(t_scored, landing, hold_s), target_m, acks)


def _score(case: Case, out: Path, heights: list[tuple[float, float]], entries: list[dict[str, Any]],
           estimates: list[tuple[float, dict[str, Any]]], window: Window, target_m: float,
           acks: dict[int, dict[str, Any]], **extra: Any) -> dict[str, Any]:  # fmt: skip
    dump_jsonl(out / f"truth{SYSID}.jsonl", [(t, {"height_m": h}) for t, h in heights])
    dump_jsonl(out / f"estimates{SYSID}.jsonl", estimates)
    # The autopilot's own altitude is what the "seen" series and seen_error_m carry here.
    steps = [{**e, "distance_m": e.get("vehicle_alt_m")} for e in entries if e.get("kind") == "step"]
    figures = height_metrics(heights, target_m, steps, estimates, window)
    figures["own_minus_true_m"] = own_minus_true(heights, steps, window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=acks.get(SYSID),
                   truth_samples=len(heights), **extra)  # fmt: skip
    return figures


def own_minus_true(heights: list[tuple[float, float]], steps: list[dict[str, Any]], window: Window) -> dict[str, Any]:
    """The autopilot's reported altitude less the true height at the same moment (nearest truth sample), over
    the scored window: ``mean`` is how far the autopilot's belief sits from the truth, ``last_10s`` its
    mean over the window's last 10 s (where a ramped lie has settled)."""
    if not heights:
        return {**_rms_max([]), "mean": None, "last_10s": None}
    times = np.array([t for t, _ in heights])
    gaps: list[tuple[float, float]] = []
    for s in steps:
        t, own = float(s["wall_s"]), s.get("vehicle_alt_m")
        if own is None or not _in(window, t):
            continue
        j = int(np.clip(np.searchsorted(times, t), 0, len(heights) - 1))
        gaps.append((t, float(own) - heights[j][1]))
    late = [g for t, g in gaps if t >= window.end_s - 10.0]
    return {
        **_rms_max([g for _, g in gaps]),
        "mean": round(float(np.mean([g for _, g in gaps])), 3) if gaps else None,
        "last_10s": round(float(np.mean(late)), 3) if late else None,
    }


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    autopilot = "ardupilot" if opts.sitl is not None else "flightsim"
    target_m = float(load_scenario(SCENARIO[autopilot]).vehicles[0].target.distance_m)  # type: ignore[union-attr]
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    log = out / f"controller{SYSID}.jsonl"
    log.unlink(missing_ok=True)
    fly = _fly_ardupilot if autopilot == "ardupilot" else _fly_flightsim
    figures = await fly(case, opts, out, log, target_m)
    figures["autopilot"] = autopilot
    return figures


def summary(figures: dict[str, Any]) -> str:
    gap = figures["own_minus_true_m"]
    late = gap.get("last_10s")
    own = f"autopilot's altitude - truth {late:+.2f} m (last 10 s)" if late is not None else "no autopilot altitude"
    flagged = figures["flagged_by_proxy"] or "none"
    return f"{held_summary(figures, 'height', 'touched ground')}, {own}, flagged by proxy {flagged}"

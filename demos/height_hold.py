"""The height-hold demo: the wall-hover demo's problem flown on ArduCopter SITL, with the ground as the wall.

ArduPilot's SITL simulates no wall, and every rangefinder it simulates reads along one direction
(docs/ardupilot.md), so the honest equivalent of the wall demo is height hold over ground on three
downward rangefinders (``demos/ardupilot/rangefinders.parm``). ``scenarios/ardupilot_height.yaml``
gives the proxy's secure stage those three as the redundant group; the controller
(``demos/controllers/height_hold.py``, pymavlink, GUIDED velocity targets) holds 5 m on the mean of the
readings it is not told are attacked. Each case boots a fresh SITL (:mod:`demos.sitl`) and runs as the
other demos do: an embedded broker, ``secuav-proxy --record`` dialling SITL's tcp port, the controller
on the proxy's ground side, the attack pushed over MQTT ``settle_s`` into the hold, the rest scored.

Ground truth is SITL's own, never the controller's belief: SIM_STATE on SITL's second serial port
(tcp 5762+10*I), which the proxy does not carry; the height above ground is its altitude less the
altitude it had on the ground before arming.
"""

from __future__ import annotations

import sys
from typing import Any

from demos.flight import Case, FlightProgress, Options, dump_jsonl, hold_on_sitl
from demos.mqtt_tap import Tap
from demos.scoring import Window, height_metrics, held_summary
from demos.sitl import Sitl, Truth, tcp_port
from demos.stack import Processes, tool
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.scenario import load_scenario

SCENARIO = "ardupilot_height"
CONTROLLER = "demos.controllers.height_hold"
AUTOPILOTS = ("ardupilot",)  # SITL simulates the ground, not a wall: the wall-hover demo is flightsim's
DEFAULT_ATTACK = "height-spoof-one"
DEFAULT_SECURE = "secekf"
SYSID = 1
BOOT_S = 60.0  # SITL opens its tcp port within a second or two; the rest of its boot waits for the proxy
ARMED_S = 300.0  # ArduPilot arms once its EKF has converged, 40-45 s after boot on a loaded machine


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    if opts.sitl is None:
        raise ValueError("the height-hold demo flies ArduPilot SITL: Options.sitl is required")
    target_m = load_scenario(SCENARIO).vehicles[0].target.distance_m
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    log = out / f"controller{SYSID}.jsonl"
    log.unlink(missing_ok=True)
    p, sitl_opts = opts.ports, opts.sitl
    topics = [vehicle_topic(SYSID, "estimate"), vehicle_topic(SYSID, "attack", "state")]
    truth = Truth(tcp_port(sitl_opts.instance, serial=1), SYSID)
    bar = FlightProgress(case.slug, opts.settle_s + opts.seconds, opts.progress)
    bar.phase("starting SITL, broker, proxy")
    async with (
        bar,
        Sitl(sitl_opts.binary, sitl_opts.instance, SYSID, sitl_opts.speedup) as sitl,
        EmbeddedBroker(port=p.mqtt),
        Tap("127.0.0.1", p.mqtt, topics) as tap,
        Processes(out) as procs,
    ):
        await sitl.ready(BOOT_S)
        await procs.start("proxy", [
            tool("secuav-proxy"), "--scenario", SCENARIO, "--secure", case.secure, "--broker", p.broker_url,
            "--record", str(out / "record"), "--vehicle", f"tcp://127.0.0.1:{tcp_port(sitl_opts.instance)}",
            "--ground", f"udpout://127.0.0.1:{p.api}", "--ground", f"udpout://127.0.0.1:{p.gcs}",
            "--stats-interval", "5",
        ])  # fmt: skip
        truth.start()
        await procs.start("controller1", [
            sys.executable, "-m", CONTROLLER, "--url", f"udpin://127.0.0.1:{p.api}", "--seconds", str(opts.seconds),
            "--log", str(log), "--altitude", str(target_m), "--target", str(target_m),
        ])  # fmt: skip
        flown = await hold_on_sitl(bar, tap, procs, log, case, opts, truth, SYSID, ARMED_S,
                                   arming="waiting for ArduPilot to arm, taking off")  # fmt: skip
    heights, estimates = flown.heights, flown.estimates
    dump_jsonl(out / f"truth{SYSID}.jsonl", [(t, {"height_m": h}) for t, h in heights])
    dump_jsonl(out / f"estimates{SYSID}.jsonl", estimates)
    window = Window(start_s=flown.t_scored, end_s=flown.landing, hold_s=flown.hold_s)
    steps = [e for e in flown.entries if e.get("kind") == "step"]
    figures = height_metrics(heights, target_m, steps, estimates, window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=flown.acks.get(SYSID),
                   ground_alt_m=round(flown.ground_m, 3), truth_samples=len(heights))  # fmt: skip
    return figures


def summary(figures: dict[str, Any]) -> str:
    flagged = figures["flagged_by_proxy"] or "none"
    return f"{held_summary(figures, 'height', 'touched ground')}, flagged by proxy {flagged}"

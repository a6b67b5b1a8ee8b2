"""The command-tamper demo: the attack reaches the vehicle through its commands and its mission.

A pymavlink ground station (``demos/controllers/command_tamper.py``) behind ``secuav-proxy`` uploads a
mission (takeoff, one waypoint 30 m east of home, RTL) and reads it back, then arms, asks for a takeoff
to 5 m, and once the climb is over starts the mission and flies to the waypoint. The attack
(``demos/profiles/command-tamper.yaml``: the rules of the library profiles ``takeoff-altitude`` and
``mission-shift`` in one profile) rewrites NAV_TAKEOFF's altitude to ``altitude_m`` and moves the uploaded
waypoints ``north_m``/``east_m``, restoring them in the read-back. The proxy runs with ``--record``; the
recording's index names every frame it changed.

Scored from the simulator's truth, never from what the ground station is told: ArduCopter SITL's
SIM_STATE on its second serial port (:class:`demos.sitl.Truth`), or secuav-sim's ``secuav/v1/truth``.
Takeoff: the maximum true height from the takeoff command to the mission start, and the settled
height (median of the last 2 s of it). Mission: the true closest horizontal approach to the waypoint
the ground station sent and to where the attack moves it. Read-back: item by item against what was sent.

The secure stage guards sensor readings (docs/security.md); it has no view of commands or missions, so
its cases are expected to match the secure-off ones: they are in the matrix to show exactly that.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time
from collections import Counter
from contextlib import AsyncExitStack
from pathlib import Path
from typing import Any

from demos.flight import Case, FlightProgress, Options, attack_payload, dump_jsonl, read_jsonl, wait_for_event
from demos.mqtt_tap import Tap
from demos.sitl import Sitl, Truth, tcp_port
from demos.stack import Processes, tool
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import Home

GROUND_STATION = "demos.controllers.command_tamper"
GS = "controller1"  # its process name: demos.stack lets a "controller..." end on its own (the others must not)
AUTOPILOTS = ("flightsim", "ardupilot")
PROFILE = Path(__file__).resolve().parent / "profiles" / "command-tamper.yaml"
DEFAULT_ATTACK = str(PROFILE)
DEFAULT_SECURE = "secekf"
SCENARIO = {"ardupilot": "ardupilot_height", "flightsim": "anchors8"}  # what the secure stage guards
SYSID = 1
TAKEOFF_M, WAYPOINT_EAST_M, MISSION_ALT_M = 5.0, 30.0, 10.0
BOOT_S = 60.0
READY_S = {"ardupilot": 420.0, "flightsim": 90.0}  # to "armed": ArduPilot's EKF and GPS take a minute to allow it
ON_HEIGHT_M = 1.0  # a settled height this close to an altitude is "at" it
ON_WAYPOINT_M = 4.0  # a closest approach this close is "flew to" it (ArduCopter's WPNAV_RADIUS is 2 m)
SETTLED_S = 2.0
# message ids counted in the recording's index (what the proxy changed, by message and direction)
COUNTED = {76: "COMMAND_LONG", 75: "COMMAND_INT", 73: "MISSION_ITEM_INT", 39: "MISSION_ITEM"}


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    autopilot = "ardupilot" if opts.sitl is not None else "flightsim"
    scenario = SCENARIO[autopilot]
    params = opts.attack_params or {}
    payload = None if case.attack is None else attack_payload(case.attack, params)  # a bad --param: before SITL boots
    values = attack_values(case.attack, params)
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    log = out / f"{GS}.jsonl"
    log.unlink(missing_ok=True)
    p = opts.ports
    topics = [vehicle_topic(SYSID, "truth"), vehicle_topic(SYSID, "attack", "state"), vehicle_topic(SYSID, "stats")]
    bar = FlightProgress(case.slug, 0.0, opts.progress)
    truth: Truth | None = None
    async with AsyncExitStack() as stack:
        await stack.enter_async_context(bar)
        if opts.sitl is not None:
            bar.phase("starting SITL")
            sitl = await stack.enter_async_context(Sitl(opts.sitl.binary, opts.sitl.instance, SYSID,
                                                        opts.sitl.speedup))  # fmt: skip
            await sitl.ready(BOOT_S)
        bar.phase("starting broker, proxy")
        await stack.enter_async_context(EmbeddedBroker(port=p.mqtt))
        tap = await stack.enter_async_context(Tap("127.0.0.1", p.mqtt, topics))
        procs = await stack.enter_async_context(Processes(out))
        proxy = [tool("secuav-proxy"), "--scenario", scenario, "--secure", case.secure, "--broker", p.broker_url,
                 "--record", str(out / "record"), "--stats-interval", "5"]  # fmt: skip
        if opts.sitl is not None:
            proxy += ["--vehicle", f"tcp://127.0.0.1:{tcp_port(opts.sitl.instance)}",
                      "--ground", f"udpout://127.0.0.1:{p.api}", "--ground", f"udpout://127.0.0.1:{p.gcs}"]  # fmt: skip
        else:  # the GCS port too, so QGroundControl or MAVProxy can watch
            proxy += ["--link", f"udpin://127.0.0.1:{p.proxy_vehicle}", f"udpout://127.0.0.1:{p.api}",
                      f"udpout://127.0.0.1:{p.gcs}"]  # fmt: skip
        await procs.start("proxy", proxy)
        acks = await _apply(tap, payload, procs)  # before the ground station says anything
        if opts.sitl is not None:
            truth = Truth(tcp_port(opts.sitl.instance, serial=1), SYSID).start()
        else:
            seed = [] if opts.seed is None else ["--seed", str(opts.seed)]
            sim = f"udpout://127.0.0.1:{p.proxy_vehicle}"
            await procs.start("sim", [tool("secuav-sim"), scenario, "--mavlink", sim, "--broker", p.broker_url, *seed])
        await procs.start(GS, [
            sys.executable, "-m", GROUND_STATION, "--url", f"udpin://127.0.0.1:{p.api}", "--autopilot", autopilot,
            "--log", str(log), "--takeoff", str(TAKEOFF_M), "--wp-east", str(WAYPOINT_EAST_M),
            "--mission-alt", str(MISSION_ALT_M),
        ])  # fmt: skip
        try:
            bar.phase("uploading the mission, waiting to arm" if truth else "uploading the mission, arming")
            await wait_for_event(log, "armed", procs, GS, READY_S[autopilot])
            bar.phase("taking off")
            await wait_for_event(log, "mission-start", procs, GS, 120.0)
            bar.phase("flying the mission")
            await wait_for_event(log, "done", procs, GS, 180.0)
        finally:
            if truth is not None:
                truth.stop()
        stats = [s.payload for s in tap.on(vehicle_topic(SYSID, "stats"))]
        sim_truth = [(s.wall_s, s.payload) for s in tap.on(vehicle_topic(SYSID, "truth"))]
    # the proxy has stopped: its recording is closed
    events = {e["event"]: e for e in read_jsonl(log) if e.get("kind") == "event"}
    if truth is not None:
        if truth.error:
            raise RuntimeError(truth.error)
        positions = sitl_positions(truth, events)
    else:
        positions = flightsim_positions(sim_truth)
    dump_jsonl(out / f"truth{SYSID}.jsonl", [(t, {"pos_ned_m": list(ned)}) for t, ned in positions])
    figures = score(events, positions, autopilot, values)
    figures.update(proxy_counts(out / "record" / f"v{SYSID}" / "index.json", stats[-1] if stats else None))
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, autopilot=autopilot,
                   attack_ack=acks, truth_samples=len(positions))  # fmt: skip
    return figures


async def _apply(tap: Tap, payload: dict[str, Any] | None, procs: Processes) -> dict[str, Any] | None:
    """The case's attack over MQTT, retried until the proxy's control plane is up (a few seconds after start)."""
    if payload is None:
        return None
    end = time.monotonic() + 30.0
    while True:
        procs.check_alive()
        try:
            ack = await tap.request(vehicle_topic(SYSID, "attack", "set"), payload, timeout_s=3.0)
        except TimeoutError:
            if time.monotonic() > end:
                raise
            continue
        if not ack.get("ok"):
            name = payload.get("name") or payload.get("library")
            raise RuntimeError(f"the proxy rejected attack {name!r}: {ack.get('error')}")
        return ack


def attack_values(attack: str | None, params: dict[str, Any]) -> dict[str, Any]:
    """The parameters the case's profile runs with (its declared defaults, then ``--param``); without an attack,
    the demo profile's, so the attack-off cases are scored against where the attack would have put things."""
    from attack_profiles.resolve import resolve_profile

    declared = resolve_profile(attack or DEFAULT_ATTACK).parameters
    profile = resolve_profile(attack or DEFAULT_ATTACK, {k: v for k, v in params.items() if k in declared})
    return {k: p.default for k, p in profile.parameters.items()}


def sitl_positions(truth: Truth, events: dict[str, Any]) -> list[tuple[float, tuple[float, float, float]]]:
    """SITL's true position in NED about the home the ground station read (down from the ground's altitude)."""
    home = _home(events)
    heights, _ = truth.heights(float(events.get("armed", {}).get("wall_s", math.inf)))
    alt = dict(heights)
    out = []
    for t, lat, lon in truth.positions:
        n, e, _ = geodetic_to_ned(home, lat, lon, home.alt_m)
        out.append((t, (n, e, -alt[t])))
    return out


def flightsim_positions(samples: list[tuple[float, dict[str, Any]]]) -> list[tuple[float, tuple[float, float, float]]]:
    """secuav-sim's truth: NED about the scenario's origin, which is also the home it reports (HOME_POSITION)."""
    return [(t, tuple(float(c) for c in d["pos_ned_m"])) for t, d in samples]  # type: ignore[misc]


def _home(events: dict[str, Any]) -> Home:
    h = events.get("home")
    if h is None:
        raise RuntimeError("the ground station logged no home position")
    return Home(lat_deg=h["lat_deg"], lon_deg=h["lon_deg"], alt_m=h["alt_m"])


def score(events: dict[str, Any], positions: list[tuple[float, tuple[float, float, float]]], autopilot: str,
          params: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """The figures of one case from the ground station's events and the simulator's true positions."""
    from demos.controllers.command_tamper import first_compared

    home = _home(events)
    for needed in ("takeoff-sent", "mission-start", "done", "mission-sent", "mission-read"):
        if needed not in events:
            raise RuntimeError(f"the ground station logged no {needed!r} event")
    if not positions:
        raise RuntimeError("no ground truth from the simulator: nothing to score")
    asked = float(events["takeoff-sent"]["altitude_m"])
    attacker_m = float(params.get("altitude_m", math.nan))
    t0, t1, t2 = (float(events[k]["wall_s"]) for k in ("takeoff-sent", "mission-start", "done"))
    climb = [-ned[2] for t, ned in positions if t0 <= t <= t1]
    settled = [-ned[2] for t, ned in positions if t1 - SETTLED_S <= t <= t1]
    max_h = max(climb, default=math.nan)
    settled_h = statistics.median(settled) if settled else math.nan

    sent, back = events["mission-sent"]["items"], events["mission-read"]["items"]
    wp = sent[1 + first_compared(autopilot)]
    wn, we, _ = geodetic_to_ned(home, wp["x"] * 1e-7, wp["y"] * 1e-7, home.alt_m)
    north, east = float(params.get("north_m", 0.0)), float(params.get("east_m", 0.0))
    flown = [(ned[0], ned[1]) for t, ned in positions if t1 <= t <= t2]
    to_sent = min((math.hypot(n - wn, e - we) for n, e in flown), default=math.nan)
    to_shifted = min((math.hypot(n - wn - north, e - we - east) for n, e in flown), default=math.nan)
    diffs = events["mission-read"]["differences"]
    return {
        "takeoff": {
            "message": events["takeoff-sent"].get("message"),
            "asked_m": asked,
            "attacker_m": attacker_m,
            "max_true_height_m": round(max_h, 3),
            "settled_true_height_m": round(settled_h, 3),
            "reported_height_m": events.get("climbed", {}).get("vehicle_alt_m"),
            "outcome": _height_outcome(settled_h, asked, attacker_m),
        },
        "mission": {
            "items_sent": len(sent),
            "items_read_back": len(back),
            "items_compared": max(0, len(sent) - first_compared(autopilot)),
            "read_back_equal": not diffs,
            "read_back_differences": diffs,
            "waypoint_sent_ned_m": [round(wn, 2) + 0.0, round(we, 2) + 0.0],  # + 0.0: no "-0.0" in the report
            "waypoint_shifted_ned_m": [round(wn + north, 2) + 0.0, round(we + east, 2) + 0.0],
            "closest_to_sent_m": round(to_sent, 2),
            "closest_to_shifted_m": round(to_shifted, 2),
            "waypoint_reached_by_vehicle": "waypoint-reached" in events,
            "outcome": _mission_outcome(to_sent, to_shifted),
        },
        "series": {
            "height": [(round(t - t0, 3), round(-ned[2], 3)) for t, ned in positions if t >= t0],
            "to_sent": [
                (round(t - t0, 3), round(math.hypot(ned[0] - wn, ned[1] - we), 2)) for t, ned in positions if t >= t0
            ],
        },
    }


def _height_outcome(settled: float, asked: float, attacker: float) -> str:
    if abs(settled - asked) <= ON_HEIGHT_M:
        return "climbed to the height asked"
    if abs(settled - attacker) <= ON_HEIGHT_M:
        return "climbed to the attacker's height"
    return "climbed to neither"


def _mission_outcome(to_sent: float, to_shifted: float) -> str:
    if to_sent <= ON_WAYPOINT_M and to_sent <= to_shifted:  # equal: a profile that moves nothing
        return "flew to the waypoint sent"
    if to_shifted <= ON_WAYPOINT_M:
        return "flew to the shifted waypoint"
    return "reached neither"


def proxy_counts(index: Path, last_stats: dict[str, Any] | None) -> dict[str, Any]:
    """What the proxy changed: frames by message and direction from the recording's index, totals from its stats."""
    changed: Counter[str] = Counter()
    if index.exists():
        text = index.read_text(encoding="utf-8").strip()
        try:
            entries = json.loads(text if text.endswith("]") else text + "]")  # a proxy killed leaves it open
        except ValueError:
            entries = []
        for e in entries:
            if e.get("changed") and not e.get("injected") and e.get("msgid") in COUNTED:
                changed[f"{COUNTED[e['msgid']]} {e['direction']}"] += 1
    totals = None
    if last_stats is not None:
        totals = {d: {k: last_stats[d][k] for k in ("frames_in", "rewritten", "injected", "dropped")}
                  for d in ("uplink", "downlink")}  # fmt: skip
    return {"rewritten_frames": dict(sorted(changed.items())), "proxy_stats": totals}


def summary(figures: dict[str, Any]) -> str:
    t, m = figures["takeoff"], figures["mission"]
    counts = ", ".join(f"{k} {v}" for k, v in figures["rewritten_frames"].items()) or "none"
    return (
        f"takeoff asked {t['asked_m']:g} m: true max {t['max_true_height_m']:.2f} m, settled "
        f"{t['settled_true_height_m']:.2f} m ({t['outcome']}); mission read-back "
        f"{'equal' if m['read_back_equal'] else 'DIFFERENT'} ({m['items_compared']} items), closest to sent "
        f"{m['closest_to_sent_m']:.1f} m / shifted {m['closest_to_shifted_m']:.1f} m ({m['outcome']}); "
        f"rewritten: {counts}"
    )

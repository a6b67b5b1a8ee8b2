"""``secuav-demo wall-hover|localise|formation|height-hold|rangefinder-feed|vision|command-tamper``: fly a demo.

wall-hover, localise and formation fly ``secuav-sim`` (``--autopilot flightsim``); height-hold flies
ArduCopter SITL (``--autopilot ardupilot``), whose binary is built outside the package (docs/ardupilot.md);
rangefinder-feed flies either (ArduCopter SITL by default), holding altitude on the vehicle from a
companion's rangefinders that the attack rewrites on their way to it (docs/ardupilot.md); vision flies
PX4 SIH (``--autopilot px4``, docs/px4.md), built outside the package too; command-tamper flies either
flightsim or ArduCopter SITL, its takeoff and mission rewritten on their way to the vehicle.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from attack_profiles.resolve import is_file_ref, resolve_profile
from demos import command_tamper, formation, height_hold, localise, px4, rangefinder_feed, sitl, vision, wall_hover
from demos.flight import Case, Options
from demos.report import plot, write_report
from demos.stack import Ports
from secuav_common.extras import require
from secuav_common.loading import parse_params
from secuav_common.logs import add_common_flags

DEMOS: dict[str, ModuleType] = {
    "wall-hover": wall_hover, "localise": localise, "formation": formation, "height-hold": height_hold,
    "rangefinder-feed": rangefinder_feed,
    "vision": vision,
    "command-tamper": command_tamper,
}  # fmt: skip
AUTOPILOTS = ("flightsim", "ardupilot", "px4")
NO_SITL = 3  # exit code: the demo needs an ArduPilot or PX4 SITL binary and none was found (docs/interfaces.md)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-demo", description=__doc__.splitlines()[0])
    p.add_argument("demo", choices=list(DEMOS),
                   help="wall-hover, localise, formation fly secuav-sim; height-hold flies the wall-hover "
                   "problem on ArduCopter SITL, as height over ground on three downward rangefinders "
                   "(docs/ardupilot.md); rangefinder-feed holds altitude on the vehicle itself from three rangefinders "
                   "a companion feeds it through the proxy, lied to on their way (docs/ardupilot.md); vision flies "
                   "PX4 SIH holding position on external vision fed through the proxy (docs/px4.md); "
                   "command-tamper rewrites a takeoff command and an uploaded mission on their way to the "
                   "vehicle (flightsim or ardupilot) (docs/ardupilot.md)")  # fmt: skip
    p.add_argument("--autopilot", choices=AUTOPILOTS, default=None,
                   help="the vehicle: flightsim (secuav-sim; wall-hover, localise, formation, command-tamper), "
                   "ardupilot (ArduCopter SITL; height-hold, command-tamper), px4 (PX4 SIH; vision); "
                   "rangefinder-feed flies flightsim or ardupilot, ardupilot by default "
                   "(default: the demo's)")  # fmt: skip
    p.add_argument("--attack", default=None,
                   help="library profile name or profile file; 'none' for no attack (default: the demo's)")  # fmt: skip
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="parameter of the attack profile, a library one or a file that declares it (JSON value), "
                   "repeatable")  # fmt: skip
    p.add_argument("--secure", default=None, help="estimator of the secure stage, or 'off' (default: the demo's)")
    p.add_argument("--matrix", action="store_true", help="all four combinations of attack on/off and secure on/off "
                   "(the default when neither --attack nor --secure is given)")  # fmt: skip
    p.add_argument("--scenario", default=None, metavar="NAME|FILE",
                   help="wall-hover, localise, formation: fly this scenario instead of the demo's own, a bundled "
                   "name, a plugin's (docs/plugins.md) or a file, of the demo's shape (docs/bench.md)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=40.0, help="hold time per flight (default 40)")
    p.add_argument("--settle", type=float, default=5.0, help="seconds of hold before the attack and the scoring start")
    p.add_argument("--seed", type=int, default=None, help="flightsim's noise seed (default: the scenario's)")
    p.add_argument("--out", type=Path, default=None, help="output directory (default out/<demo>)")
    p.add_argument("--base-port", type=int, default=None,
                   help="ports BASE+i (proxy), BASE+10+i (MAVSDK), BASE+20 (GCS), BASE+21 (MQTT), BASE+9 "
                   "(rangefinder-feed's companion feed) instead of the port plan in docs/interfaces.md")  # fmt: skip
    p.add_argument("--broker-port", type=int, default=None, metavar="N",
                   help="the demo's own broker on 127.0.0.1:N (default 1883, or the --base-port block's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar per flight")
    sim = p.add_argument_group("ArduPilot SITL and PX4 SIH (--autopilot ardupilot, px4)")
    sim.add_argument("--sitl-binary", type=Path, default=None,
                     help="ArduCopter SITL binary (default: $ARDUPILOT_BIN, else latest/arducopter in "
                     "$SECUAV_ARDUPILOT_CACHE, which defaults to ~/.cache/secuav/ardupilot); with px4 the px4 "
                     "binary (default: $PX4_BIN, else latest/bin/px4 in $SECUAV_PX4_CACHE, ~/.cache/secuav/px4)",
                     )  # fmt: skip
    sim.add_argument("--instance", type=int, default=None,
                     help=f"SITL instance I: MAVLink on tcp 5760+10*I, truth on 5762+10*I "
                     f"(default {sitl.DEFAULT_INSTANCE}); with px4 PX4's instance (its ports 18570+I, "
                     f"default {px4.DEFAULT_INSTANCE})")  # fmt: skip
    sim.add_argument("--speedup", type=float, default=None, help="SITL's speed-up over real time (default 1)")
    p.add_argument("-v", "--verbose", action="store_true")
    add_common_flags(p, log_flags=False)
    return p


def cases(demo: ModuleType, attack: str | None, secure: str | None, matrix: bool) -> list[Case]:
    hit = None if attack == "none" else (attack or demo.DEFAULT_ATTACK)
    if not matrix:
        return [Case(hit, secure or demo.DEFAULT_SECURE)]
    on = secure if secure not in (None, "off") else demo.DEFAULT_SECURE
    hit = hit or demo.DEFAULT_ATTACK
    return [Case(None, "off"), Case(hit, "off"), Case(None, on), Case(hit, on)]


def attack_params(demo: ModuleType, attack: str | None, given: dict[str, Any]) -> dict[str, Any]:
    """The parameters the attack flies with: for a library profile the demo's defaults that it declares, then
    ``--param``; for a profile file ``--param`` alone (its own defaults stand: a study's cell writes its resolved
    profile there). A bad profile or a ``--param`` it does not declare: ``InputError``, one line, before anything
    flies."""
    defaults: dict[str, Any] = getattr(demo, "DEFAULT_PARAMS", {})
    if attack is None:
        return {**defaults, **given}
    declared = {} if is_file_ref(attack) else resolve_profile(attack, flag="--attack").parameters
    params = {**{k: v for k, v in defaults.items() if k in declared}, **given}
    resolve_profile(attack, params, flag="--attack")
    return params


def check_autopilot(args: argparse.Namespace) -> str | None:
    """Fill in ``args.autopilot``; the one-line reason the flags do not fit the demo, or None."""
    flies = DEMOS[args.demo].AUTOPILOTS
    args.autopilot = args.autopilot or flies[0]
    if args.autopilot not in flies:
        why = " (ArduPilot's SITL simulates no wall: docs/ardupilot.md)" if args.demo == "wall-hover" else ""
        return f"{args.demo} flies on {' or '.join(flies)}, not {args.autopilot}{why}"
    sitl_flags = [f for f, v in (("--sitl-binary", args.sitl_binary), ("--instance", args.instance),
                                 ("--speedup", args.speedup)) if v is not None]  # fmt: skip
    if args.autopilot == "flightsim" and sitl_flags:
        return f"{', '.join(sitl_flags)}: only with --autopilot ardupilot or px4"
    if args.autopilot == "px4" and args.speedup is not None:
        return "--speedup: only with --autopilot ardupilot (PX4 SIH runs in real time here)"
    if args.autopilot == "ardupilot" and args.seed is not None:
        return "--seed: flightsim's noise seed; ArduPilot SITL draws its own"
    if args.autopilot == "px4" and args.seed is not None:
        return "--seed: flightsim's noise seed; PX4 SIH draws its own (the feed's noise is the scenario's seed)"
    if args.instance is not None and args.instance < 0:
        return f"--instance: a non-negative integer, got {args.instance}"
    if args.speedup is not None and args.speedup <= 0:
        return f"--speedup: a positive number, got {args.speedup:g}"
    return None if args.scenario is None else check_scenario(args.demo, args.scenario)


def check_scenario(demo: str, name: str) -> str | None:
    """Why ``--scenario`` cannot be flown by ``demo`` (one line), or None."""
    from demos.catalog import SCENARIO_OF_DEMO, demo_for
    from secuav_common.loading import InputError
    from secuav_common.scenario import load_scenario

    if demo not in SCENARIO_OF_DEMO:
        return f"--scenario: only wall-hover, localise and formation fly another scenario, not {demo}"
    try:
        scenario = load_scenario(name)
    except InputError as err:
        return f"--scenario: {err}"
    try:
        flies = demo_for(scenario)
    except ValueError as exc:
        return f"--scenario {name}: {exc}"
    return None if flies == demo else f"--scenario {name}: a {flies} scenario, not a {demo} one"


def sitl_options(args: argparse.Namespace) -> sitl.SitlOptions | None:
    """The SITL to fly for ``--autopilot ardupilot`` (``sitl.NoSitl`` when there is no binary), else None."""
    if args.autopilot != "ardupilot":
        return None
    binary = sitl.find_binary(args.sitl_binary)
    sitl.copter_defaults(binary)
    instance = sitl.DEFAULT_INSTANCE if args.instance is None else args.instance
    return sitl.SitlOptions(binary, instance, 1.0 if args.speedup is None else args.speedup)


def ports_of(args: argparse.Namespace) -> Ports:
    """The run's loopback ports: the port plan, or the ``--base-port`` block; ``--broker-port`` moves the broker
    alone (a shared host whose 1883 is someone else's)."""
    ports = Ports() if args.base_port is None else Ports.block(args.base_port)
    return ports if args.broker_port is None else dataclasses.replace(ports, mqtt=args.broker_port)


def px4_options(args: argparse.Namespace) -> px4.Px4Options | None:
    """The PX4 to fly for ``--autopilot px4`` (``px4.NoPx4`` when there is no binary), else None."""
    if args.autopilot != "px4":
        return None
    binary = px4.find_binary(args.sitl_binary)
    return px4.Px4Options(binary, px4.DEFAULT_INSTANCE if args.instance is None else args.instance)


async def _main(args: argparse.Namespace, sim: sitl.SitlOptions | None, px4_opts: px4.Px4Options | None = None) -> int:
    demo = DEMOS[args.demo]
    out = args.out or Path("out") / args.demo
    matrix = args.matrix or (args.attack is None and args.secure is None)
    ports = ports_of(args)
    selected = cases(demo, args.attack, args.secure, matrix)
    params = attack_params(demo, next((c.attack for c in selected if c.attack), None), parse_params(args.param))
    opts = Options(out=out, seconds=args.seconds, settle_s=args.settle, seed=args.seed, ports=ports,
                   attack_params=params, progress=not args.no_progress and sys.stderr.isatty(), sitl=sim,
                   px4=px4_opts, scenario=args.scenario)  # fmt: skip
    settings: dict[str, object] = {"autopilot": args.autopilot}
    if args.scenario is not None:
        settings["scenario"] = args.scenario
    if sim is not None:
        built = sitl.build_info(sim.binary)
        settings.update(ardupilot=built, sitl_binary=str(sim.binary), sitl_instance=sim.instance,
                        sitl_speedup=sim.speedup)  # fmt: skip
        print(f"ArduPilot SITL {built.get('version', '?')} built from {built.get('commit', '?')}: {sim.binary}, "
              f"instance {sim.instance} (tcp {sitl.tcp_port(sim.instance)}), speedup {sim.speedup:g}",
              flush=True)  # fmt: skip
    if px4_opts is not None:
        built = px4.build_info(px4_opts.binary)
        settings.update(px4=built, px4_binary=str(px4_opts.binary), px4_instance=px4_opts.instance)
        print(f"PX4 SIH {built['commit']}: {px4_opts.binary}, instance {px4_opts.instance}", flush=True)
    results = []
    for i, case in enumerate(selected, 1):
        print(f"[{i}/{len(selected)}] {args.demo} {case.slug} (attack {case.attack or 'none'}, secure {case.secure})",
              flush=True)  # fmt: skip
        figures = await demo.run_case(case, opts)
        print(f"    {demo.summary(figures)}", flush=True)
        results.append(figures)
    settings.update(matrix=matrix, seconds=args.seconds, settle_s=args.settle, seed=args.seed, attack_params=params,
                    cases=[[c.attack, c.secure] for c in selected])  # fmt: skip
    print(f"report: {write_report(out, args.demo, settings, results)}\nplot:   {plot(out, args.demo, results)}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    bad = check_autopilot(args)
    if bad is not None:
        parser.error(bad)
    require("secuav-demo")
    try:
        sim = sitl_options(args)
        px4_opts = px4_options(args)
    except (sitl.NoSitl, px4.NoPx4) as exc:
        print(f"secuav-demo: {exc}", file=sys.stderr)
        return NO_SITL
    level = logging.INFO if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s %(message)s")
    loop = asyncio.new_event_loop()
    task = loop.create_task(_main(args, sim, px4_opts))
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError):
            loop.add_signal_handler(sig, task.cancel)
    try:
        return loop.run_until_complete(task)
    except asyncio.CancelledError:
        print("secuav-demo: interrupted; every process was stopped", file=sys.stderr)
        return 130
    except (RuntimeError, TimeoutError, ValueError, OSError) as exc:
        print(f"secuav-demo: {exc}", file=sys.stderr)
        return 1
    finally:
        loop.close()

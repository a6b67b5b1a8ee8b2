"""``secuav-demo wall-hover|localise|formation``: fly a closed-loop demo and write a report."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from attack_profiles.resolve import parse_params
from demos import formation, localise, wall_hover
from demos.flight import Case, Options
from demos.report import plot, write_report
from demos.stack import Ports
from secuav_common.extras import require
from secuav_common.logs import add_common_flags

DEMOS: dict[str, ModuleType] = {"wall-hover": wall_hover, "localise": localise, "formation": formation}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-demo", description=__doc__.splitlines()[0])
    p.add_argument("demo", choices=list(DEMOS))
    p.add_argument("--attack", default=None,
                   help="library profile name or profile file; 'none' for no attack (default: the demo's)")  # fmt: skip
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="parameter of a library attack profile (JSON value), repeatable")  # fmt: skip
    p.add_argument("--secure", default=None, help="estimator of the secure stage, or 'off' (default: the demo's)")
    p.add_argument("--matrix", action="store_true", help="all four combinations of attack on/off and secure on/off "
                   "(the default when neither --attack nor --secure is given)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=40.0, help="hold time per flight (default 40)")
    p.add_argument("--settle", type=float, default=5.0, help="seconds of hold before the attack and the scoring start")
    p.add_argument("--seed", type=int, default=None, help="simulator noise seed (default: the scenario's)")
    p.add_argument("--out", type=Path, default=None, help="output directory (default out/<demo>)")
    p.add_argument("--base-port", type=int, default=None,
                   help="ports BASE+i (proxy), BASE+10+i (MAVSDK), BASE+20 (GCS), BASE+21 (MQTT) "
                   "instead of the port plan in docs/interfaces.md")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar per flight")
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


async def _main(args: argparse.Namespace) -> int:
    demo = DEMOS[args.demo]
    out = args.out or Path("out") / args.demo
    matrix = args.matrix or (args.attack is None and args.secure is None)
    base = args.base_port
    ports = Ports() if base is None else Ports.block(base)
    params = {**getattr(demo, "DEFAULT_PARAMS", {}), **parse_params(args.param)}
    opts = Options(out=out, seconds=args.seconds, settle_s=args.settle, seed=args.seed, ports=ports,
                   attack_params=params, progress=not args.no_progress and sys.stderr.isatty())  # fmt: skip
    selected = cases(demo, args.attack, args.secure, matrix)
    results = []
    for i, case in enumerate(selected, 1):
        print(f"[{i}/{len(selected)}] {args.demo} {case.slug} (attack {case.attack or 'none'}, secure {case.secure})",
              flush=True)  # fmt: skip
        figures = await demo.run_case(case, opts)
        print(f"    {demo.summary(figures)}", flush=True)
        results.append(figures)
    settings = {"matrix": matrix, "seconds": args.seconds, "settle_s": args.settle, "seed": args.seed,
                "attack_params": params, "cases": [[c.attack, c.secure] for c in selected]}  # fmt: skip
    print(f"report: {write_report(out, args.demo, settings, results)}\nplot:   {plot(out, args.demo, results)}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    require("secuav-demo")
    level = logging.INFO if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s %(message)s")
    loop = asyncio.new_event_loop()
    task = loop.create_task(_main(args))
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

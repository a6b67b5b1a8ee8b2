"""``secuav-demo wall-hover|localise|formation``: fly a closed-loop demo and write a report."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from demos import wall_hover
from demos.report import plot_wall_hover, write_report
from demos.stack import Ports

DEMOS = ("wall-hover",)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-demo", description=__doc__.splitlines()[0])
    p.add_argument("demo", choices=DEMOS)
    p.add_argument("--attack", default=None, help="library profile name or profile file; 'none' for no attack "
                   f"(default: {wall_hover.DEFAULT_ATTACK})")  # fmt: skip
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="parameter of a library attack profile (JSON value), repeatable")  # fmt: skip
    p.add_argument("--secure", default=None,
                   help=f"estimator of the secure stage, or 'off' (default: {wall_hover.DEFAULT_SECURE})")  # fmt: skip
    p.add_argument("--matrix", action="store_true", help="all four combinations of attack on/off and secure on/off "
                   "(the default when neither --attack nor --secure is given)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=40.0, help="hold time per flight (default 40)")
    p.add_argument("--settle", type=float, default=5.0, help="seconds of hold before the attack and the scoring start")
    p.add_argument("--seed", type=int, default=None, help="simulator noise seed (default: the scenario's)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    p.add_argument("--base-port", type=int, default=None,
                   help="ports BASE (proxy), BASE+1 (MAVSDK), BASE+2 (GCS), BASE+3 (MQTT) "
                   "instead of the port plan")  # fmt: skip
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def _params(pairs: Sequence[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise SystemExit(f"secuav-demo: --param {pair!r}: expected KEY=VALUE")
        try:
            out[key] = json.loads(text)
        except ValueError:
            out[key] = text
    return out


async def _main(args: argparse.Namespace) -> int:
    matrix = args.matrix or (args.attack is None and args.secure is None)
    attack = None if args.attack == "none" else (args.attack or wall_hover.DEFAULT_ATTACK)
    secure = args.secure or wall_hover.DEFAULT_SECURE
    base = args.base_port
    ports = Ports() if base is None else Ports(base, base + 1, base + 2, base + 3)
    opts = wall_hover.Options(
        out=args.out, seconds=args.seconds, settle_s=args.settle, seed=args.seed, ports=ports,
        attack_params=_params(args.param),
    )  # fmt: skip
    selected = wall_hover.cases(attack, secure, matrix)
    results = await wall_hover.run(selected, opts, progress=lambda line: print(line, flush=True))
    settings = {"attack": attack, "secure": secure, "matrix": matrix, "seconds": args.seconds, "settle_s": args.settle,
                "seed": args.seed, "attack_params": opts.attack_params}  # fmt: skip
    report = write_report(args.out, "wall-hover", settings, results)
    figure = plot_wall_hover(args.out, results)
    print(f"report: {report}\nplot:   {figure}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
    except (RuntimeError, TimeoutError, ValueError) as exc:
        print(f"secuav-demo: {exc}", file=sys.stderr)
        return 1
    finally:
        loop.close()

"""``secuav-sim [SCENARIO] [--speed X] [--mavlink URL]... [--gcs URL] [--broker URL] [--truth-csv F] [--seed N]``.

Runs every vehicle of a scenario with a PX4 personality on MAVLink 2.
Vehicle i (sysid i+1) sends to the proxy at ``udpout://127.0.0.1:(14560+i)``
by default; one ``--mavlink URL`` moves vehicle i to URL's port + i, or give
one ``--mavlink`` per vehicle. ``--gcs URL`` streams every vehicle to one more
fixed peer as well (QGroundControl on 14550 beside MAVSDK on 14540, as PX4 SITL
does). Bad input is one line on stderr and exit 2; nothing starts.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from secuav_common.broker import parse_broker_url, secret_or_env
from secuav_common.controlplane.address import with_port
from secuav_common.extras import require
from secuav_common.loading import InputError
from secuav_common.logs import add_common_flags, cli_error, setup_logging
from secuav_common.ports import proxy_vehicle_url
from secuav_common.scenario import DEFAULT_SCENARIO, Scenario, load_scenario
from secuav_common.urls import Endpoint, parse_endpoint

PROG = "secuav-sim"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Run the vehicles of a scenario, PX4-like over MAVLink 2.")
    p.add_argument(
        "scenario",
        nargs="?",
        default=str(DEFAULT_SCENARIO),
        help="scenario file or bundled name (wall_hover, anchors8, formation); default wall_hover",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="clock factor: 1 = wall clock (default, needed with MAVSDK), 0 = as fast as possible",
    )
    p.add_argument("--fast", action="store_true", help="as fast as possible (same as --speed 0)")
    p.add_argument(
        "--mavlink",
        action="append",
        metavar="URL",
        default=[],
        help="udpout://HOST:PORT, udpin://HOST:PORT or tcpin://HOST:PORT (a TCP server, as SITL's 5760); "
        "once (vehicle i uses PORT+i) or once per vehicle; "
        "default udpout://127.0.0.1:14560+i (the proxy)",
    )
    p.add_argument(
        "--gcs",
        metavar="URL",
        help="udpout://HOST:PORT every vehicle also streams to, e.g. QGroundControl/MAVProxy on "
        "udpout://127.0.0.1:14550 when running without the proxy",
    )
    p.add_argument("--broker", metavar="URL", help="publish ground truth to mqtt://HOST[:PORT] (secuav/v<sysid>/truth)")
    p.add_argument("--broker-port", type=int, metavar="N",
                   help="the broker's port: without --broker, publish ground truth to mqtt://127.0.0.1:N")
    p.add_argument("--broker-tls-ca", metavar="FILE", type=Path,
                   help="CA file of a TLS broker (mqtts://) signed by a private CA")  # fmt: skip
    p.add_argument("--broker-username", metavar="NAME", help="broker account (or in the URL: mqtt://NAME@HOST)")
    p.add_argument("--broker-password-file", metavar="F", type=Path,
                   help="broker password from F (mode 600); SECUAV_BROKER_PASSWORD works too")  # fmt: skip
    p.add_argument("--truth-csv", metavar="FILE", type=Path, help="write ground truth to a CSV file")
    p.add_argument("--truth-hz", type=float, default=20.0, help="ground-truth sample rate (default 20 Hz)")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="stop after S simulated seconds (default: run until stopped; with --speed 0 the scenario's duration_s)",
    )
    p.add_argument("--seed", type=int, help="noise seed (default: the scenario's seed)")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    add_common_flags(p)
    return p  # fmt: skip


def endpoints_for(urls: Sequence[str], scenario: Scenario) -> list[Endpoint]:
    """One endpoint per vehicle: the default plan, one URL offset by the vehicle index, or one URL each."""
    n = len(scenario.vehicles)
    if not urls:
        return [parse_endpoint(proxy_vehicle_url(i)) for i in range(n)]
    parsed = [parse_endpoint(u) for u in urls]
    for url, ep in zip(urls, parsed, strict=True):
        if ep.mode not in ("udpin", "udpout", "tcpin") or ep.options:
            raise ValueError(f"--mavlink {url}: the simulator serves udpin://, udpout:// or tcpin://HOST:PORT "
                             "(a TCP server like SITL's 5760)")  # fmt: skip
    if len(parsed) == n:
        return parsed
    if len(parsed) == 1:
        base = parsed[0]
        if base.port + n - 1 > 65535:
            raise ValueError(f"--mavlink {urls[0]}: port {base.port} + {n - 1} vehicles exceeds 65535")
        return [Endpoint(base.mode, base.host, base.port + i) for i in range(n)]
    raise ValueError(f"--mavlink given {len(parsed)} times; give it once or once per vehicle ({n})")


def _fail(message: str, code: int = 2) -> int:
    return cli_error(PROG, message, code)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    require("secuav-sim")
    try:
        scenario = load_scenario(args.scenario)
        endpoints = endpoints_for(args.mavlink, scenario)
        url = args.broker or (None if args.broker_port is None else "mqtt://127.0.0.1")
        broker = parse_broker_url(with_port(url, args.broker_port)) if url else None
        if broker is not None:
            username = args.broker_username or broker.username
            password = secret_or_env(args.broker_password_file, "--broker-password-file") or broker.password
            broker = replace(broker, username=username, password=password)
        gcs = parse_endpoint(args.gcs) if args.gcs else None
        if gcs is not None and (gcs.mode != "udpout" or gcs.options):
            raise ValueError(f"--gcs {args.gcs}: must be udpout://HOST:PORT (the GCS listens there)")
        if gcs is not None and any(ep.mode == "tcpin" for ep in endpoints):
            raise ValueError(f"--gcs {args.gcs}: with --mavlink tcpin:// the GCS connects to that TCP port instead")
    except (InputError, ValueError) as exc:
        return _fail(str(exc))
    speed = 0.0 if args.fast else args.speed
    if not speed >= 0:
        return _fail(f"--speed {args.speed}: must be 0 (as fast as possible) or positive")
    if args.duration is not None and not args.duration > 0:
        return _fail(f"--duration {args.duration}: must be positive")
    if not args.truth_hz > 0:
        return _fail(f"--truth-hz {args.truth_hz}: must be positive")
    duration = args.duration if args.duration is not None else (scenario.duration_s if speed == 0 else None)
    setup_logging(args.verbose, args.quiet, noisy=("aiomqtt", "asyncio", "jsbsim"), json_lines=args.log_json)

    from flightsim.runner import RunConfig  # after validation: bad input never pays for JSBSim

    config = RunConfig(scenario, endpoints, args.seed, speed, duration, broker, args.truth_csv, args.truth_hz, gcs,
                       broker_tls_ca=args.broker_tls_ca)  # fmt: skip
    try:
        return asyncio.run(_serve(config))
    except OSError as exc:
        return _fail(f"cannot open MAVLink socket: {exc.strerror or exc}", 1)
    except KeyboardInterrupt:
        return 130


async def _serve(config: object) -> int:
    from flightsim.runner import RunConfig, SimRunner

    assert isinstance(config, RunConfig)
    log = logging.getLogger(PROG)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError):
            loop.add_signal_handler(sig, stop.set)
    mode = "as fast as possible" if config.speed == 0 else f"{config.speed:g}x wall clock"
    log.info("sim.start", extra={"scenario": config.scenario.name, "vehicles": len(config.scenario.vehicles),
                                 "clock": mode, "seed": config.seed if config.seed is not None
                                 else config.scenario.seed})  # fmt: skip
    async with SimRunner(config) as runner:
        summary = await runner.run(stop)
    log.info("sim.stop", extra={
        "sim_t_s": round(summary.sim_t_s, 2), "wall_s": round(summary.wall_s, 2),
        "rtf": round(summary.real_time_factor, 2), "frames_sent": sum(summary.frames_sent.values()),
        "frames_received": sum(summary.frames_received.values()), "malformed": sum(summary.malformed.values()),
        "crashed": ",".join(f"v{s}" for s in summary.crashed) or "none",
    })  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

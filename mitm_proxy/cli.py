"""``secuav-proxy``: the MAVLink man-in-the-middle daemon.

With no flags it serves one vehicle on the port plan of docs/interfaces.md: listens on
``udpin://127.0.0.1:14560`` and forwards to ``udpout://127.0.0.1:14540``
(MAVSDK) and ``udpout://127.0.0.1:14550`` (QGroundControl, MAVProxy).
``--vehicles N`` or ``--scenario F`` gives one link per vehicle (vehicle i on
14560+i -> 14540+i and the shared 14550). A config file (``--config F``, YAML,
same keys as :class:`mitm_proxy.config.ProxyConfig`) sets anything; flags win.
Bad input is one line on stderr and exit 2; nothing starts.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mitm_proxy.config import ProxyConfig, build_config, load_config, override_endpoints
from secuav_common.broker import secret_or_env
from secuav_common.controlplane.states import MODES
from secuav_common.loading import InputError
from secuav_common.logs import add_common_flags, cli_error, setup_logging
from secuav_common.urls import parse_endpoint

PROG = "secuav-proxy"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="MAVLink man-in-the-middle: forward, record, attack.")
    p.add_argument("--config", metavar="F", type=Path, help="YAML config file (flags win over it)")
    p.add_argument("--scenario", metavar="F", type=Path, help="one link per vehicle of this scenario (sysids from it)")
    p.add_argument("--vehicles", metavar="N", type=int, help="one link per vehicle, sysids 1..N (default 1)")
    p.add_argument(
        "--vehicle",
        metavar="URL",
        action="append",
        default=[],
        help="vehicle side (default udpin://127.0.0.1:14560+i): udpin://, udpout://, tcp:// (e.g. ArduPilot SITL's "
        "tcp://127.0.0.1:5760), tcpin://HOST:PORT or serial:///dev/ttyUSB0?baud=57600 (udp:// means udpin://; "
        "MAVSDK's udp://:PORT is refused: write udpin://127.0.0.1:PORT or udpin://0.0.0.0:PORT); "
        "once (link i uses PORT+i) or once per link",
    )
    p.add_argument(
        "--ground",
        metavar="URL",
        action="append",
        default=[],
        help="ground side, repeatable (default udpout://127.0.0.1:14540+i and :14550); same schemes as --vehicle; "
        "rules as URL options: ?listen_only=true, ?deny=DISTANCE_SENSOR,ATTITUDE (downlink), ?deny_up=, ?allow=, "
        "?allow_sysid=, ?deny_compid_up=... (see docs/routes.md); "
        "with several links each URL is one endpoint shared by all",
    )
    p.add_argument(
        "--link",
        metavar="URL",
        nargs="+",
        action="append",
        default=[],
        help="VEHICLE_URL GROUND_URL...: one link, repeat once per vehicle in order",
    )
    p.add_argument(
        "--profile",
        metavar="F",
        help="initial attack profile: a file (reloaded on change) or a library name (secuav-attack list)",
    )
    p.add_argument("--attack", choices=MODES, help="attack stage active or bypassed (default on)")
    p.add_argument("--secure", metavar="NAME", help="secure estimator, or off (default off); "
                   "`secuav-plugins --estimator NAME` lists its parameters")  # fmt: skip
    p.add_argument("--secure-direction", choices=("downlink", "uplink", "both"),
                   help="where the secure stage reads its sensor group and substitutes the estimate: downlink "
                   "(toward the ground, default), uplink (the frames the autopilot receives) or both")  # fmt: skip
    p.add_argument("--no-uplink-attacks", action="store_true", default=None,
                   help="refuse any attack profile with a rule toward the vehicle (direction uplink or both), "
                   "whichever way it arrives; the previous profile stays")  # fmt: skip
    p.add_argument(
        "--broker",
        metavar="URL",
        help="embedded (default: amqtt on 127.0.0.1:1883 or --broker-port, or the broker already there), "
        "mqtt://[user:pass@]HOST[:PORT], mqtts://..., or none",
    )
    p.add_argument("--broker-port", type=int, metavar="N",
                   help="the broker's port: --broker embedded starts it on 127.0.0.1:N (default 1883), "
                   "a --broker URL without a port gets N")
    p.add_argument("--broker-username", metavar="NAME",
                   help="broker account; with --broker embedded that broker then admits this account only")
    p.add_argument("--broker-password", metavar="PASS",
                   help="visible to every user in ps: prefer --broker-password-file or SECUAV_BROKER_PASSWORD")
    p.add_argument("--broker-password-file", metavar="F", type=Path,
                   help="read the broker password from F (mode 600); SECUAV_BROKER_PASSWORD works too")  # fmt: skip
    p.add_argument("--broker-tls-ca", metavar="F", type=Path, help="CA file for mqtts://")
    p.add_argument("--instance", metavar="NAME",
                   help="this proxy's name on the broker, unique per broker (default <host>-<pid>)")  # fmt: skip
    p.add_argument(
        "--record", metavar="DIR", type=Path,
        help="write DIR/v<sysid>/original.tlog, forwarded.tlog, index.json and profiles.json"
    )
    p.add_argument("--signing-key", metavar="F", type=Path, help="MAVLink 2 signing key: verify, re-sign changes")
    p.add_argument("--seed", type=int, help="seed of the attack engine's random primitives (default 0)")
    p.add_argument(
        "--stats-interval",
        metavar="S",
        type=float,
        dest="stats_interval_s",
        help="seconds between stats lines (default 5)",
    )
    p.add_argument(
        "--loop", choices=("auto", "uvloop", "asyncio"), default="auto", help="event loop (auto: uvloop when installed)"
    )
    p.add_argument("--print-config", action="store_true",
                   help="print the configuration as it would run (file + flags, defaults, routing rules) and exit")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    add_common_flags(p)
    return p  # fmt: skip


FLAG_KEYS = ("scenario", "vehicles", "profile", "attack", "secure", "secure_direction", "no_uplink_attacks",
             "broker", "broker_port", "broker_username", "broker_password", "broker_tls_ca", "instance", "record",
             "signing_key", "seed", "stats_interval_s")  # fmt: skip


def config_from_args(args: argparse.Namespace) -> ProxyConfig:
    """File, then flags, then the endpoint flags; ``InputError``/``ValueError`` on bad input."""
    file_values: dict[str, Any] = load_config(args.config) if args.config else {}
    source = str(args.config) if args.config else "<flags>"
    flags = {k: getattr(args, k) for k in FLAG_KEYS}
    if args.link:
        if args.vehicle or args.ground:
            raise ValueError("--link cannot be combined with --vehicle/--ground")
        flags["links"] = _links_from_flag(args.link, args, file_values)
    if flags["broker_password"] is None:
        flags["broker_password"] = secret_or_env(args.broker_password_file, "--broker-password-file")
    cfg = build_config(file_values, flags, source)
    if args.vehicle or args.ground:
        cfg = override_endpoints(cfg, args.vehicle, args.ground, "<flags>")
    return cfg


def _links_from_flag(groups: list[list[str]], args: argparse.Namespace, file_values: dict[str, Any]) -> list[dict]:
    for group in groups:
        for url in group:
            parse_endpoint(url)
        if len(group) < 2:
            raise ValueError(f"--link {' '.join(group)}: give the vehicle URL and at least one ground URL")
    scenario = args.scenario or file_values.get("scenario")
    if scenario is not None:
        from secuav_common.scenario import load_scenario

        sysids = [v.sysid for v in load_scenario(scenario).vehicles]
        if len(sysids) != len(groups):
            raise ValueError(f"--link given {len(groups)} times; the scenario {scenario} has {len(sysids)} vehicles")
    else:
        sysids = list(range(1, len(groups) + 1))
    return [{"sysid": s, "vehicle": g[0], "ground": g[1:]} for s, g in zip(sysids, groups, strict=True)]


def _fail(message: str, code: int = 2) -> int:
    return cli_error(PROG, message, code)


def new_event_loop(choice: str) -> asyncio.AbstractEventLoop:
    """uvloop when asked for or (``auto``) installed; the standard loop otherwise."""
    if choice != "asyncio":
        try:
            import uvloop
        except ImportError:
            if choice == "uvloop":
                raise
        else:
            return uvloop.new_event_loop()
    return asyncio.new_event_loop()


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    noisy = ("aiomqtt", "asyncio", "amqtt", "transitions")
    # Warnings only while the proxy is built: installing a --profile may warn (attack.true_copy), and a record
    # logged before any handler exists reaches stderr as its bare message, without level or fields. The
    # start-up settings' INFO lines stay out: proxy.ready says them once (and an error stays one line).
    setup_logging(0, True, noisy=noisy, json_lines=args.log_json)
    try:
        cfg = config_from_args(args)
        if args.print_config:
            import yaml

            from mitm_proxy.config import effective

            print(yaml.safe_dump(effective(cfg), sort_keys=False), end="")
            return 0
        from mitm_proxy.app import Proxy, serve  # after the config: bad flags never pay for the imports

        proxy = Proxy(cfg)  # reads the scenario, profile and key: their errors come before any socket
    except (InputError, ValueError) as exc:
        return _fail(str(exc))
    setup_logging(args.verbose, args.quiet, noisy=noisy, json_lines=args.log_json)
    try:
        loop = new_event_loop(args.loop)
    except ImportError:
        return _fail("--loop uvloop: uvloop is not installed")
    try:
        with asyncio.Runner(loop_factory=lambda: loop) as runner:
            return runner.run(serve(proxy))
    except OSError as exc:
        return _fail(f"cannot open a socket: {exc.strerror or exc}", 1)
    except InputError as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""``secuav-attack status`` and every runtime switch's verbs (``apply``, ``clear``, ``mode``, ``secure``,
``routes``): the live subcommands, over MQTT.

The offline subcommands live in :mod:`attack_profiles.cli`; this module adds
``status`` and every switch's verbs to its parser. Each verb is declared in one
small module per switch (:mod:`mitm_proxy.tools.verbs`: its arguments, the
request it sends, the line it prints), and this module runs any of them the
same way: the request is built and checked here first (a typo
fails at once, with the file and field named), sent with a fresh
``request_id`` leading the JSON, and the command waits for the ``.../state``
that carries that id: the proxy's own verdict, not just the broker's receipt.

A vehicle switch's verb without ``--vehicle`` goes to every vehicle that has
a retained state of that switch on the broker (else an ``attack/state``), i.e.
every link of the running proxies. With ``--vehicle N`` it fails at once (exit 3, naming the vehicles each
proxy serves) when the proxies' online records say none of them serves N. A proxy-wide switch's verb has ``show``
(``routes show``) and ``set`` actions on one instance (``--instance`` when
several are online). ``status`` lists every proxy instance on the broker and
its vehicles (``--watch``: a live table).

Exit codes: 0 accepted; 1 bad input or rejected by the proxy (the reason on
stderr); 2 usage; 3 no broker, no proxy, or no acknowledgement in time.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import sys
import time
import uuid
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any

from attack_profiles import cli as profiles_cli
from mitm_proxy.tools import verbs as switches
from mitm_proxy.tools.board import Board
from mitm_proxy.tools.verbs import SwitchVerbs, Verb
from secuav_common.broker import read_secret
from secuav_common.controlplane.address import parse_broker_url, with_port
from secuav_common.controlplane.session import Client, MqttError, messages
from secuav_common.controlplane.session import Session as MqttSession
from secuav_common.controlplane.topics import ANY, INSTANCES_ONLINE, PROXY_ONLINE, proxy_topic, vehicle_topic
from secuav_common.loading import InputError

DEFAULT_HOST = "mqtt://127.0.0.1"
DEFAULT_BROKER = f"{DEFAULT_HOST}:1883"
EXIT_OK, EXIT_REJECTED, EXIT_USAGE, EXIT_UNREACHABLE = 0, 1, 2, 3
VEHICLE_HELP = "only this vehicle's sysid"


def add_options(command: str, parser: argparse.ArgumentParser) -> None:
    """Transport options of the live subcommands."""
    parser.add_argument(
        "--broker", default=None, metavar="URL", help=f"MQTT broker (default {DEFAULT_BROKER})"
    )
    parser.add_argument("--broker-port", type=int, metavar="N",
                        help="the broker's port (the one secuav-proxy --broker-port N started; default 1883)")
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for the proxy (5)")
    parser.add_argument("--tls-ca", metavar="FILE", help="CA file for a TLS broker (mqtts://)")
    parser.add_argument("--username", metavar="NAME", help="broker user (or in the URL: mqtt://NAME@HOST)")
    parser.add_argument("--password-file", metavar="F", type=Path,
                        help="broker password from F (mode 600); SECUAV_BROKER_PASSWORD works too")  # fmt: skip
    found = switches.owner(command)
    if command == "status" or (found is not None and found[0].scope == "proxy"):
        parser.add_argument("--json", action="store_true", help="print what the broker holds as one JSON document")
    if command == "status":
        parser.add_argument("--watch", action="store_true", help="a live table, redrawn until Ctrl-C")
        parser.add_argument("--interval", type=float, default=1.0, metavar="S", help="--watch redraw period (1 s)")


async def _listen(client: Client, board: Board) -> None:
    async for topic, raw, _retained in messages(client):
        board.receive(topic, raw)


Body = Callable[[Client, Board], Awaitable[int]]


def _session(args: argparse.Namespace, topics: list[str], body: Body) -> int:
    """Connect, subscribe, run ``body``; broker trouble becomes one line and exit 3."""
    try:
        args.broker = with_port(args.broker or DEFAULT_HOST, args.broker_port) if args.broker_port else (
            args.broker or DEFAULT_BROKER)  # every message below then names the real port
        address = parse_broker_url(args.broker)
        password = address.password
        if password is None and args.password_file is not None:
            password = read_secret(args.password_file, "--password-file").decode("utf-8").strip()
        password = password or os.environ.get("SECUAV_BROKER_PASSWORD") or None
    except ValueError as exc:
        print(f"secuav-attack: --broker: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except InputError as exc:
        print(f"secuav-attack: {exc}", file=sys.stderr)
        return EXIT_USAGE
    session = MqttSession(address, identifier=f"secuav-attack-{uuid.uuid4().hex[:8]}", username=args.username,
                          password=password, tls_ca=args.tls_ca, timeout_s=args.timeout)  # fmt: skip

    async def run() -> int:
        board = Board()
        async with session.client() as client:
            listener = asyncio.create_task(_listen(client, board))
            try:
                await client.subscribe([(t, 1) for t in topics])
                board.last_arrival_s = time.monotonic()
                return await body(client, board)
            finally:
                listener.cancel()
                with contextlib.suppress(asyncio.CancelledError, MqttError):
                    await listener

    try:
        return asyncio.run(run())
    except MqttError as exc:
        print(f"secuav-attack: cannot use the broker at {address.url}: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE


def _served_elsewhere(board: Board, sysid: int) -> str | None:
    """Which vehicles the online proxies serve, when their online records say none serves ``sysid``; else None.

    No online record at all (an older proxy, one still connecting) says nothing: the request is then sent and
    waits for its acknowledgement as before.
    """
    online = {name: rec for name, rec in board.instances().items() if rec.get("online") is True}
    if not online or any(sysid in (rec.get("vehicles") or ()) for rec in online.values()):
        return None
    return "; ".join(f"{name} serves " + (", ".join(f"v{v}" for v in rec.get("vehicles") or ()) or "no vehicle")
                     for name, rec in online.items())  # fmt: skip


def _online(board: Board) -> str:
    value = board.latest.get(PROXY_ONLINE)
    return "online" if value is True else "offline" if value is False else "unknown"


async def _request(
    client: Client, board: Board, args: argparse.Namespace, spec: SwitchVerbs, verb: Verb, body: Any
) -> int:
    """Send ``body`` to each target vehicle's ``<kind>/set`` and report each verdict; the worst exit code wins."""
    leaf = spec.kind
    if args.vehicle is not None:
        vehicles = [args.vehicle]
        await board.settle(args.timeout)
        if (elsewhere := _served_elsewhere(board, args.vehicle)) is not None:
            print(f"secuav-attack: v{args.vehicle}: no proxy on the broker at {args.broker} serves vehicle "
                  f"{args.vehicle} ({elsewhere})", file=sys.stderr)  # fmt: skip
            return EXIT_UNREACHABLE
    else:
        await board.settle(args.timeout)
        vehicles = board.vehicles(spec.state_leaf) or board.vehicles()
        if not vehicles:
            print(
                f"secuav-attack: no proxy on the broker at {args.broker} (no retained "
                f"{vehicle_topic(ANY, leaf, 'state')}); is secuav-proxy running with this --broker?",
                file=sys.stderr,
            )
            return EXIT_UNREACHABLE
    requests = [(vehicle_topic(sysid, leaf, "set"), body) for sysid in vehicles]
    states = await board.acks.request_all(client, requests, args.timeout)

    worst = EXIT_OK
    for sysid, state in zip(vehicles, states, strict=True):
        if state is None:
            print(
                f"secuav-attack: v{sysid}: no acknowledgement within {args.timeout:g} s "
                f"(proxy {_online(board)}; is vehicle {sysid} one of its links? may your broker account "
                "publish requests? a broker drops what its ACL forbids, silently)",
                file=sys.stderr,
            )
            worst = max(worst, EXIT_UNREACHABLE)
        elif not state.get("ok"):
            print(f"secuav-attack: v{sysid}: rejected: {state.get('error')}", file=sys.stderr)
            worst = max(worst, EXIT_REJECTED)
        else:
            print(verb.done(f"v{sysid}", state, args))
            for warning in state.get("warnings") or ():  # applied, but something keeps it from acting fully
                print(f"secuav-attack: v{sysid}: warning: {warning}", file=sys.stderr)
    return worst


def run_verb(spec: SwitchVerbs, verb: Verb, args: argparse.Namespace) -> int:
    """Any switch's verb: build (and check) its request before the broker is involved, then send it."""
    if spec.scope == "proxy":
        body = verb.request(args) if args.action == "set" else None
        topics = [proxy_topic(ANY, spec.kind, "state"), INSTANCES_ONLINE]
        return _session(args, topics, lambda c, b: _proxy_verb(c, b, args, spec, verb, body))
    body = verb.request(args)  # InputError -> exit 1, naming the file or option
    topics = list(dict.fromkeys([vehicle_topic(ANY, spec.kind, "state"), vehicle_topic(ANY, "attack", "state"),
                                 PROXY_ONLINE, INSTANCES_ONLINE]))  # fmt: skip
    return _session(args, topics, lambda c, b: _request(c, b, args, spec, verb, body))


def _stats_line(stats: dict[str, Any]) -> str:
    parts = []
    for direction in ("downlink", "uplink"):
        d = stats.get(direction)
        if isinstance(d, dict):
            forged = ""
            if d.get("injected"):  # frames the proxy added: said only when there are some
                forged = (f", injected {d['injected']} (duplicated {d.get('duplicated', 0)}, "
                          f"replayed {d.get('replayed', 0)})")  # fmt: skip
            parts.append(
                f"{direction} {d.get('frames_in', '?')} in/{d.get('frames_out', '?')} out, "
                f"rewritten {d.get('rewritten', '?')}, dropped {d.get('dropped', '?')}{forged}, "
                f"bad {d.get('bad_total', '?')}"
            )
    lat = stats.get("latency_ms")
    if isinstance(lat, dict) and lat.get("p50") is not None:
        parts.append(f"latency p50 {lat['p50']:.2f} ms p99 {lat['p99']:.2f} ms")
    endpoints = stats.get("endpoints")
    for name, ep in endpoints.items() if isinstance(endpoints, dict) else ():
        if isinstance(ep, dict) and ep.get("muted"):  # nobody listens on its port (docs/interfaces.md)
            parts.append(f"{name} muted ({ep.get('muted_dropped', '?')} datagrams not sent)")
    return "; ".join(parts) or json.dumps(stats, separators=(",", ":"))


def _leaves() -> list[str]:
    """What ``status`` reads of each vehicle: every vehicle switch's state, then the stats."""
    return [*(spec.state_leaf for spec in switches.switches() if spec.scope == "vehicle"), "stats"]


def _status_topics() -> list[str]:
    return [*(vehicle_topic(ANY, leaf) for leaf in _leaves()), PROXY_ONLINE, INSTANCES_ONLINE]


def _report(board: Board, vehicles: list[int]) -> dict[str, Any]:
    """What ``status --json`` prints: the proxy instances and, per vehicle, every state the broker holds."""
    report: dict[str, Any] = {"online": board.latest.get(PROXY_ONLINE), "instances": board.instances(), "vehicles": {}}
    for sysid in vehicles:
        report["vehicles"][f"v{sysid}"] = {leaf: board.latest.get(vehicle_topic(sysid, leaf)) for leaf in _leaves()}
    return report


def _instance_lines(board: Board) -> list[str]:
    """One line per proxy instance; a vehicle claimed by two online instances is said out loud."""
    lines, owners = [], {}
    for name, rec in board.instances().items():
        vehicles = [v for v in rec.get("vehicles", []) if isinstance(v, int)]
        where = f" pid {rec['pid']} on {rec.get('host')}" if rec.get("pid") else ""
        state = "online" if rec.get("online") else "offline"
        lines.append(f"proxy {name}: {state} since {switches.since_text(rec.get('since'))}{where}; "
                     f"vehicles {', '.join(f'v{v}' for v in vehicles) or 'none'}")  # fmt: skip
        if rec.get("online"):
            for v in vehicles:
                owners.setdefault(v, []).append(name)
    for v, names in sorted(owners.items()):
        if len(names) > 1:
            lines.append(f"warning: v{v} is served by {len(names)} online proxies ({', '.join(names)}): "
                         "requests reach all of them and their states overwrite each other")  # fmt: skip
    return lines or [f"proxy: {_online(board)}"]


async def _status(board: Board, args: argparse.Namespace) -> int:
    await board.settle(args.timeout)
    vehicles = board.vehicles()
    if args.vehicle is not None:
        vehicles = [v for v in vehicles if v == args.vehicle]
    if not vehicles:
        which = f"vehicle {args.vehicle}" if args.vehicle is not None else "any vehicle"
        print(f"secuav-attack: no state for {which} on the broker at {args.broker}", file=sys.stderr)
        return EXIT_UNREACHABLE
    # Stats are not retained: give the proxy one publishing period (1 s) to send them.
    await board.until(lambda: all(vehicle_topic(v, "stats") in board.latest for v in vehicles), min(1.5, args.timeout))
    report = _report(board, vehicles)
    if args.json:
        print(json.dumps(report, indent=2))
        return EXIT_OK
    for line in _instance_lines(board):
        print(line)
    printers = [spec.status for spec in switches.switches() if spec.scope == "vehicle" and spec.status is not None]
    for key, entry in report["vehicles"].items():
        for status_lines in printers:
            for line in status_lines(key, entry):
                print(line)
        for spec in switches.switches():  # what keeps a switch's stage from working, whichever switch it is
            state = entry.get(f"{spec.kind}/state")
            if spec.scope == "vehicle" and isinstance(state, dict):
                _print_warnings(key, state)
        if isinstance(entry["stats"], dict):
            print(f"{key}: {_stats_line(entry['stats'])}")
    return EXIT_OK


def _print_warnings(key: str, state: dict[str, Any]) -> None:
    """A state's ``warnings`` (what keeps its stage from working, docs/interfaces.md), one line each."""
    for warning in state.get("warnings") or []:
        print(f"{key}: warning: {warning}")  # as `apply` prints a profile's warnings


def cmd_status(args: argparse.Namespace) -> int:
    if args.watch:
        from mitm_proxy.tools.watch import watch

        return _session(args, _status_topics(), lambda c, b: watch(b, args))
    return _session(args, _status_topics(), lambda c, b: _status(b, args))


def _states_of(board: Board, kind: str) -> dict[str, dict[str, Any]]:
    """Instance -> its retained ``<kind>/state``."""
    return board.by_instance(kind, "state")


def _pick_instance(board: Board, args: argparse.Namespace, kind: str) -> str | None:
    """The instance a proxy-wide verb addresses; prints why when there is none or the choice is ambiguous."""
    known = _states_of(board, kind)
    online = [n for n in board.online_instances() if n in known] or list(known)
    if args.instance is not None:
        if args.instance in known:
            return args.instance
        print(f"secuav-attack: no proxy instance {args.instance!r} on the broker at {args.broker} "
              f"(instances: {', '.join(known) or 'none'})", file=sys.stderr)  # fmt: skip
        return None
    if len(online) == 1:
        return online[0]
    if not online:
        where = proxy_topic(ANY, kind, "state")
        print(f"secuav-attack: no proxy on the broker at {args.broker} (no retained {where})", file=sys.stderr)
    else:
        print(f"secuav-attack: {len(online)} proxies are online ({', '.join(online)}): choose one with --instance",
              file=sys.stderr)  # fmt: skip
    return None


async def _proxy_verb(
    client: Client, board: Board, args: argparse.Namespace, spec: SwitchVerbs, verb: Verb, body: Any
) -> int:
    """``<verb> show`` (one instance's state, or every one's with ``--json``) or ``<verb> set ...``."""
    await board.settle(args.timeout)
    states = _states_of(board, spec.kind)
    if args.action == "show" and args.json and args.instance is None:
        print(json.dumps(states, indent=2))
        return EXIT_OK
    name = _pick_instance(board, args, spec.kind)
    if name is None:
        return EXIT_UNREACHABLE if not states or args.instance else EXIT_USAGE
    if args.action == "show":
        if args.json or verb.show is None:
            print(json.dumps(states[name], indent=2))
        else:
            for line in verb.show(name, states[name]):
                print(line)
        return EXIT_OK
    (state,) = await board.acks.request_all(client, [(proxy_topic(name, spec.kind, "set"), body)], args.timeout)
    if state is None:
        print(f"secuav-attack: {name}: no acknowledgement within {args.timeout:g} s", file=sys.stderr)
        return EXIT_UNREACHABLE
    if not state.get("ok"):
        print(f"secuav-attack: {name}: rejected: {state.get('error')}", file=sys.stderr)
        return EXIT_REJECTED
    print(verb.done(name, state, args))
    return EXIT_OK


def _verb_handler(spec: SwitchVerbs, verb: Verb) -> Callable[[argparse.Namespace], int]:
    return lambda args: run_verb(spec, verb, args)


def add_live(sub: Any) -> None:
    """``status`` and every switch's verbs, with their transport options, on the shared parser's subcommands."""
    p = sub.add_parser("status", help="show the active profile of a running proxy")
    p.add_argument("--vehicle", type=int, metavar="N", help=VEHICLE_HELP)
    p.set_defaults(func=cmd_status)
    add_options("status", p)
    for spec, verb in switches.verbs():
        p = sub.add_parser(verb.name, help=verb.help)
        if spec.scope == "vehicle":  # sent to one vehicle, or to every vehicle on the broker
            verb.arguments(p)
            p.add_argument("--vehicle", type=int, metavar="N", help=VEHICLE_HELP)
            targets: tuple[argparse.ArgumentParser, ...] = (p,)
        else:  # proxy-wide: read one instance's state, or send it a request
            actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
            show = actions.add_parser("show", help=verb.show_help)
            change = actions.add_parser("set", help=verb.set_help)
            verb.arguments(change)
            targets = (show, change)
        for q in targets:
            if spec.scope == "proxy":
                q.add_argument("--instance", metavar="NAME", help="the proxy instance (needed when several are online)")
            q.set_defaults(func=_verb_handler(spec, verb))
            add_options(verb.name, q)


def build_parser() -> argparse.ArgumentParser:
    """The whole ``secuav-attack`` command line: the offline subcommands and the live ones."""
    return profiles_cli.build_parser(add_live)


def main(argv: Sequence[str] | None = None) -> int:
    return profiles_cli.main(argv, add_live)


if __name__ == "__main__":
    sys.exit(main())

"""``secuav-attack apply|clear|status|mode|secure|routes``: the live subcommands, over MQTT.

The offline subcommands and every parser live in :mod:`attack_profiles.cli`;
this module plugs in the three that talk to a running proxy. ``apply`` checks
the profile here first (a typo fails at once, with the file and field named),
sends the resolved profile with a fresh ``request_id`` leading the JSON, and
waits for the ``attack/state`` that carries that id: the proxy's own verdict,
not just the broker's receipt.

Without ``--vehicle`` the command goes to every vehicle that has a retained
``attack/state`` on the broker, i.e. every link of the running proxies.
``status`` lists every proxy instance on the broker and its vehicles
(``--watch``: a live table); ``routes show|set`` reads and changes one
instance's per-endpoint rules.

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
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from attack_profiles import cli as profiles_cli
from mitm_proxy.tools.board import Board
from secuav_common.broker import read_secret
from secuav_common.controlplane.address import parse_broker_url
from secuav_common.controlplane.payloads import MAX_PAYLOAD_BYTES, request_bytes
from secuav_common.controlplane.session import Client, MqttError
from secuav_common.controlplane.session import Session as MqttSession
from secuav_common.controlplane.topics import ANY, INSTANCES_ONLINE, PROXY_ONLINE, proxy_topic, vehicle_topic
from secuav_common.loading import InputError

DEFAULT_BROKER = "mqtt://127.0.0.1:1883"
EXIT_OK, EXIT_REJECTED, EXIT_USAGE, EXIT_UNREACHABLE = 0, 1, 2, 3


def add_options(command: str, parser: argparse.ArgumentParser) -> None:
    """Transport options of the live subcommands (the ``live_options`` hook of the shared parser)."""
    parser.add_argument(
        "--broker", default=DEFAULT_BROKER, metavar="URL", help=f"MQTT broker (default {DEFAULT_BROKER})"
    )
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for the proxy (5)")
    parser.add_argument("--tls-ca", metavar="FILE", help="CA file for a TLS broker (mqtts://)")
    parser.add_argument("--username", metavar="NAME", help="broker user (or in the URL: mqtt://NAME@HOST)")
    parser.add_argument("--password-file", metavar="F", type=Path,
                        help="broker password from F (mode 600); SECUAV_BROKER_PASSWORD works too")  # fmt: skip
    if command in ("status", "routes"):
        parser.add_argument("--json", action="store_true", help="print what the broker holds as one JSON document")
    if command == "status":
        parser.add_argument("--watch", action="store_true", help="a live table, redrawn until Ctrl-C")
        parser.add_argument("--interval", type=float, default=1.0, metavar="S", help="--watch redraw period (1 s)")


async def _listen(client: Client, board: Board) -> None:
    async for message in client.messages:
        raw = message.payload if isinstance(message.payload, bytes | bytearray) else b""
        board.receive(str(message.topic), bytes(raw))


Body = Callable[[Client, Board], Awaitable[int]]


def _session(args: argparse.Namespace, topics: list[str], body: Body) -> int:
    """Connect, subscribe, run ``body``; broker trouble becomes one line and exit 3."""
    try:
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


def _online(board: Board) -> str:
    value = board.latest.get(PROXY_ONLINE)
    return "online" if value is True else "offline" if value is False else "unknown"


def _attack_verdict(sysid: int, state: dict[str, Any]) -> str:
    if state.get("profile") is None:
        return f"ok: v{sysid} cleared"
    return f"ok: v{sysid} {state['profile']} (hash {str(state.get('hash'))[:12]})"


async def _request(
    client: Client,
    board: Board,
    args: argparse.Namespace,
    body: Any,
    leaf: str = "attack",
    verdict: Callable[[int, dict[str, Any]], str] = _attack_verdict,
) -> int:
    """Send ``body`` to each target vehicle's ``<leaf>/set`` and report each verdict; the worst exit code wins."""
    if args.vehicle is not None:
        vehicles = [args.vehicle]
    else:
        await board.settle(args.timeout)
        vehicles = board.vehicles(f"{leaf}/state") or board.vehicles()
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
            print(verdict(sysid, state))
            for warning in state.get("warnings") or ():  # applied, but a true copy stays on the wire
                print(f"secuav-attack: v{sysid}: warning: {warning}", file=sys.stderr)
    return worst


def cmd_apply(args: argparse.Namespace) -> int:
    profile = profiles_cli._resolve(args.profile, profiles_cli._params(args.param))
    body = json.loads(profile.canonical_json())
    size = len(request_bytes(body, uuid.uuid4().hex))
    if size > MAX_PAYLOAD_BYTES:
        raise InputError(args.profile, "", size, f"the proxy accepts profiles up to {MAX_PAYLOAD_BYTES} bytes of JSON")
    topics = [vehicle_topic(ANY, "attack", "state"), PROXY_ONLINE]
    return _session(args, topics, lambda c, b: _request(c, b, args, body))


def cmd_clear(args: argparse.Namespace) -> int:
    topics = [vehicle_topic(ANY, "attack", "state"), PROXY_ONLINE]
    return _session(args, topics, lambda c, b: _request(c, b, args, None))


def cmd_mode(args: argparse.Namespace) -> int:
    """``mode on|bypass``: switch the attack stage, keeping its profile."""
    topics = [vehicle_topic(ANY, "attack/mode", "state"), vehicle_topic(ANY, "attack", "state"), PROXY_ONLINE]
    return _session(args, topics, lambda c, b: _request(
        c, b, args, {"mode": args.mode}, "attack/mode", lambda s, st: f"ok: v{s} attack {st.get('mode')}"
    ))  # fmt: skip


def cmd_secure(args: argparse.Namespace) -> int:
    """``secure NAME|off``: choose the secure stage's estimator (with --param k=v), or bypass it."""
    body: dict[str, Any] = {"estimator": args.estimator}
    if args.param:
        body["params"] = profiles_cli._params(args.param)

    def verdict(sysid: int, state: dict[str, Any]) -> str:
        return f"ok: v{sysid} secure {state.get('estimator') or 'off'}"

    topics = [vehicle_topic(ANY, "secure", "state"), vehicle_topic(ANY, "attack", "state"), PROXY_ONLINE]
    return _session(args, topics, lambda c, b: _request(c, b, args, body, "secure", verdict))


def _since(epoch_s: Any) -> str:
    if not isinstance(epoch_s, int | float):
        return "-"
    return datetime.fromtimestamp(epoch_s, UTC).strftime("%Y-%m-%d %H:%M:%SZ")


def _stats_line(stats: dict[str, Any]) -> str:
    parts = []
    for direction in ("downlink", "uplink"):
        d = stats.get(direction)
        if isinstance(d, dict):
            parts.append(
                f"{direction} {d.get('frames_in', '?')} in/{d.get('frames_out', '?')} out, "
                f"rewritten {d.get('rewritten', '?')}, dropped {d.get('dropped', '?')}, bad {d.get('bad_total', '?')}"
            )
    lat = stats.get("latency_ms")
    if isinstance(lat, dict) and lat.get("p50") is not None:
        parts.append(f"latency p50 {lat['p50']:.2f} ms p99 {lat['p99']:.2f} ms")
    return "; ".join(parts) or json.dumps(stats, separators=(",", ":"))


LEAVES = ("attack/state", "attack/mode/state", "secure/state", "stats")
STATUS_TOPICS = [*(vehicle_topic(ANY, leaf) for leaf in LEAVES), PROXY_ONLINE, INSTANCES_ONLINE]


def _report(board: Board, vehicles: list[int]) -> dict[str, Any]:
    """What ``status --json`` prints: the proxy instances and, per vehicle, every state the broker holds."""
    report: dict[str, Any] = {"online": board.latest.get(PROXY_ONLINE), "instances": board.instances(), "vehicles": {}}
    for sysid in vehicles:
        report["vehicles"][f"v{sysid}"] = {leaf: board.latest.get(vehicle_topic(sysid, leaf)) for leaf in LEAVES}
    return report


def _instance_lines(board: Board) -> list[str]:
    """One line per proxy instance; a vehicle claimed by two online instances is said out loud."""
    lines, owners = [], {}
    for name, rec in board.instances().items():
        vehicles = [v for v in rec.get("vehicles", []) if isinstance(v, int)]
        where = f" pid {rec['pid']} on {rec.get('host')}" if rec.get("pid") else ""
        state = "online" if rec.get("online") else "offline"
        lines.append(f"proxy {name}: {state} since {_since(rec.get('since'))}{where}; "
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
    for key, entry in report["vehicles"].items():
        attack = entry["attack/state"] or {}
        active = f"{attack.get('profile')} (hash {str(attack.get('hash'))[:12]})" if attack.get("profile") else "none"
        last = "ok" if attack.get("ok") else f"rejected: {attack.get('error')}"
        mode = (entry["attack/mode/state"] or {}).get("mode")
        bypass = " (bypassed)" if mode == "bypass" else ""
        print(f"{key}: attack {active}{bypass} since {_since(attack.get('since'))}; last request {last}")
        for warning in attack.get("warnings") or ():
            print(f"{key}: warning: {warning}")
        secure = entry["secure/state"]
        if isinstance(secure, dict):
            if secure.get("available") is False:
                print(f"{key}: secure not available in this proxy")
            else:
                note = "" if secure.get("ok") else f"; last request rejected: {secure.get('error')}"
                print(f"{key}: secure {secure.get('estimator') or 'off'}{note}")
        if isinstance(entry["stats"], dict):
            print(f"{key}: {_stats_line(entry['stats'])}")
    return EXIT_OK


def cmd_status(args: argparse.Namespace) -> int:
    if args.watch:
        from mitm_proxy.tools.watch import watch

        return _session(args, STATUS_TOPICS, lambda c, b: watch(b, args))
    return _session(args, STATUS_TOPICS, lambda c, b: _status(b, args))


ROUTES_TOPICS = [proxy_topic(ANY, "routes", "state"), INSTANCES_ONLINE]


def _routes_of(board: Board) -> dict[str, dict[str, Any]]:
    """Instance -> its retained ``routes/state``."""
    return board.by_instance("routes", "state")


def _pick_instance(board: Board, args: argparse.Namespace) -> str | None:
    """The instance a routes command addresses; prints why when there is none or the choice is ambiguous."""
    known = _routes_of(board)
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
        where = proxy_topic(ANY, "routes", "state")
        print(f"secuav-attack: no proxy on the broker at {args.broker} (no retained {where})", file=sys.stderr)
    else:
        print(f"secuav-attack: {len(online)} proxies are online ({', '.join(online)}): choose one with --instance",
              file=sys.stderr)  # fmt: skip
    return None


def _print_routes(name: str, state: dict[str, Any]) -> None:
    from mitm_proxy.net.rules import EndpointRules, rules_to_query

    print(f"proxy {name}:")
    for ep_name, ep in (state.get("endpoints") or {}).items():
        try:
            spelled = rules_to_query(EndpointRules.model_validate(ep.get("rules") or {})) or "no rules"
        except ValueError:
            spelled = json.dumps(ep.get("rules"))
        print(f"  {ep_name:<16} {ep.get('role', '?'):<7} {ep.get('url')}  {spelled}")


async def _routes(client: Client, board: Board, args: argparse.Namespace) -> int:
    await board.settle(args.timeout)
    if args.routes_action == "show" and args.json and args.instance is None:
        print(json.dumps(_routes_of(board), indent=2))
        return EXIT_OK
    name = _pick_instance(board, args)
    if name is None:
        return EXIT_UNREACHABLE if not _routes_of(board) or args.instance else EXIT_USAGE
    if args.routes_action == "show":
        state = _routes_of(board)[name]
        if args.json:
            print(json.dumps(state, indent=2))
        else:
            _print_routes(name, state)
        return EXIT_OK
    rules = None if args.rules.strip().lower() in ("none", "") else _local_rules(args.rules)
    body = {"endpoints": {args.endpoint: rules}}
    (state,) = await board.acks.request_all(client, [(proxy_topic(name, "routes", "set"), body)], args.timeout)
    if state is None:
        print(f"secuav-attack: {name}: no acknowledgement within {args.timeout:g} s", file=sys.stderr)
        return EXIT_UNREACHABLE
    if not state.get("ok"):
        print(f"secuav-attack: {name}: rejected: {state.get('error')}", file=sys.stderr)
        return EXIT_REJECTED
    print(f"ok: {name} {args.endpoint} {'no rules' if rules is None else args.rules}")
    return EXIT_OK


def _local_rules(query: str) -> dict[str, Any]:
    """The rules checked here first, as the proxy will check them (a typo fails before anything is sent)."""
    from mitm_proxy.net.rules import rules_from_query

    return rules_from_query(query, "RULES").model_dump(exclude_defaults=True)


def cmd_routes(args: argparse.Namespace) -> int:
    """``routes show`` / ``routes set ENDPOINT RULES``: one instance's per-endpoint rules."""
    if args.routes_action == "set" and args.rules.strip().lower() not in ("none", ""):
        _local_rules(args.rules)  # InputError -> exit 1 with the option named, before any broker is involved
    return _session(args, ROUTES_TOPICS, lambda c, b: _routes(c, b, args))


def main(argv: Sequence[str] | None = None) -> int:
    return profiles_cli.main(
        argv,
        live_handlers={"apply": cmd_apply, "clear": cmd_clear, "status": cmd_status, "mode": cmd_mode,
                       "secure": cmd_secure, "routes": cmd_routes},
        live_options=add_options,
    )


if __name__ == "__main__":
    sys.exit(main())

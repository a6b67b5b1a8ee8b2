"""``secuav-attack apply|clear|status``: the live subcommands, over the proxy's MQTT control plane.

The offline subcommands and every parser live in :mod:`attack_profiles.cli`;
this module plugs in the three that talk to a running proxy. ``apply`` checks
the profile here first (a typo fails at once, with the file and field named),
sends the resolved profile with a fresh ``request_id`` leading the JSON, and
waits for the ``attack/state`` that carries that id: the proxy's own verdict,
not just the broker's receipt.

Without ``--vehicle`` the command goes to every vehicle that has a retained
``attack/state`` on the broker, i.e. every link of the running proxy.

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
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import aiomqtt

from attack_profiles import cli as profiles_cli
from mitm_proxy.control import MAX_PAYLOAD_BYTES, ONLINE_TOPIC, PREFIX, parse_vehicle_key, vehicle_topic
from secuav_common.broker import parse_broker_url, read_secret
from secuav_common.loading import InputError

DEFAULT_BROKER = "mqtt://127.0.0.1:1883"
EXIT_OK, EXIT_REJECTED, EXIT_USAGE, EXIT_UNREACHABLE = 0, 1, 2, 3
SETTLE_S = 0.3  # retained messages follow the SUBACK at once; this long without one means we have them all


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
    if command == "status":
        parser.add_argument("--json", action="store_true", help="print what the broker holds as one JSON document")


@dataclass
class Board:
    """Everything seen on the subscribed topics, latest per topic, and who is waiting for what."""

    latest: dict[str, Any] = field(default_factory=dict)
    last_arrival_s: float = field(default_factory=time.monotonic)
    changed: asyncio.Event = field(default_factory=asyncio.Event)

    def vehicles(self, leaf: str = "attack/state") -> list[int]:
        found = set()
        for topic in self.latest:
            parts = topic.split("/")
            sysid = parse_vehicle_key(parts[1]) if len(parts) == 4 and f"{parts[2]}/{parts[3]}" == leaf else None
            if sysid is not None:
                found.add(sysid)
        return sorted(found)

    async def settle(self, limit_s: float) -> None:
        """Wait until no message came for :data:`SETTLE_S` (the retained ones are in) or ``limit_s`` passed."""
        deadline = time.monotonic() + limit_s
        while (now := time.monotonic()) < deadline:
            quiet_s = now - self.last_arrival_s
            if quiet_s >= SETTLE_S:
                return
            await asyncio.sleep(min(SETTLE_S - quiet_s, deadline - now))

    async def until(self, done: Callable[[], bool], limit_s: float) -> bool:
        deadline = time.monotonic() + limit_s
        while not done():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.changed.clear()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self.changed.wait(), remaining)
        return True


async def _listen(client: aiomqtt.Client, board: Board, answers: dict[str, dict[str, Any]]) -> None:
    async for message in client.messages:
        raw = message.payload if isinstance(message.payload, bytes | bytearray) else b""
        try:
            body = json.loads(raw) if raw else None
        except ValueError:
            continue
        board.latest[str(message.topic)] = body
        board.last_arrival_s = time.monotonic()
        if isinstance(body, dict) and isinstance(body.get("request_id"), str):
            answers[body["request_id"]] = body
        board.changed.set()


Session = Callable[[aiomqtt.Client, Board, dict[str, dict[str, Any]]], Awaitable[int]]


def _session(args: argparse.Namespace, topics: list[str], body: Session) -> int:
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
    tls = aiomqtt.TLSParameters(ca_certs=args.tls_ca) if address.tls or args.tls_ca else None

    async def run() -> int:
        board, answers = Board(), {}
        async with aiomqtt.Client(
            address.host,
            address.port,
            username=args.username or address.username,
            password=password,
            identifier=f"secuav-attack-{uuid.uuid4().hex[:8]}",
            timeout=args.timeout,
            tls_params=tls,
        ) as client:
            listener = asyncio.create_task(_listen(client, board, answers))
            try:
                await client.subscribe([(t, 1) for t in topics])
                board.last_arrival_s = time.monotonic()
                return await body(client, board, answers)
            finally:
                listener.cancel()
                with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                    await listener

    try:
        return asyncio.run(run())
    except aiomqtt.MqttError as exc:
        print(f"secuav-attack: cannot use the broker at {address.url}: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE


def _online(board: Board) -> str:
    value = board.latest.get(ONLINE_TOPIC)
    return "online" if value is True else "offline" if value is False else "unknown"


def _attack_verdict(sysid: int, state: dict[str, Any]) -> str:
    if state.get("profile") is None:
        return f"ok: v{sysid} cleared"
    return f"ok: v{sysid} {state['profile']} (hash {str(state.get('hash'))[:12]})"


async def _request(
    client: aiomqtt.Client,
    board: Board,
    answers: dict[str, dict[str, Any]],
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
                f"secuav-attack: no proxy on the broker at {args.broker} (no retained {PREFIX}/+/{leaf}/state); "
                "is secuav-proxy running with this --broker?",
                file=sys.stderr,
            )
            return EXIT_UNREACHABLE
    pending: dict[str, int] = {}
    for sysid in vehicles:
        request_id = uuid.uuid4().hex
        pending[request_id] = sysid
        payload = json.dumps({"request_id": request_id, **body} if body is not None else {"request_id": request_id})
        await client.publish(vehicle_topic(sysid, f"{leaf}/set"), payload.encode(), qos=1)
    await board.until(lambda: all(rid in answers for rid in pending), args.timeout)

    worst = EXIT_OK
    for request_id, sysid in pending.items():
        state = answers.get(request_id)
        if state is None:
            print(
                f"secuav-attack: v{sysid}: no acknowledgement within {args.timeout:g} s "
                f"(proxy {_online(board)}; is vehicle {sysid} one of its links?)",
                file=sys.stderr,
            )
            worst = max(worst, EXIT_UNREACHABLE)
        elif not state.get("ok"):
            print(f"secuav-attack: v{sysid}: rejected: {state.get('error')}", file=sys.stderr)
            worst = max(worst, EXIT_REJECTED)
        else:
            print(verdict(sysid, state))
    return worst


def cmd_apply(args: argparse.Namespace) -> int:
    profile = profiles_cli._resolve(args.profile, profiles_cli._params(args.param))
    body = json.loads(profile.canonical_json())
    size = len(json.dumps({"request_id": uuid.uuid4().hex, **body}).encode())
    if size > MAX_PAYLOAD_BYTES:
        raise InputError(args.profile, "", size, f"the proxy accepts profiles up to {MAX_PAYLOAD_BYTES} bytes of JSON")
    topics = [f"{PREFIX}/+/attack/state", ONLINE_TOPIC]
    return _session(args, topics, lambda c, b, a: _request(c, b, a, args, body))


def cmd_clear(args: argparse.Namespace) -> int:
    topics = [f"{PREFIX}/+/attack/state", ONLINE_TOPIC]
    return _session(args, topics, lambda c, b, a: _request(c, b, a, args, None))


def cmd_mode(args: argparse.Namespace) -> int:
    """``mode on|bypass``: switch the attack stage, keeping its profile."""
    topics = [f"{PREFIX}/+/attack/mode/state", f"{PREFIX}/+/attack/state", ONLINE_TOPIC]
    return _session(args, topics, lambda c, b, a: _request(
        c, b, a, args, {"mode": args.mode}, "attack/mode", lambda s, st: f"ok: v{s} attack {st.get('mode')}"
    ))  # fmt: skip


def cmd_secure(args: argparse.Namespace) -> int:
    """``secure NAME|off``: choose the secure stage's estimator (with --param k=v), or bypass it."""
    body: dict[str, Any] = {"estimator": args.estimator}
    if args.param:
        body["params"] = profiles_cli._params(args.param)

    def verdict(sysid: int, state: dict[str, Any]) -> str:
        return f"ok: v{sysid} secure {state.get('estimator') or 'off'}"

    topics = [f"{PREFIX}/+/secure/state", f"{PREFIX}/+/attack/state", ONLINE_TOPIC]
    return _session(args, topics, lambda c, b, a: _request(c, b, a, args, body, "secure", verdict))


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
    report: dict[str, Any] = {"online": board.latest.get(ONLINE_TOPIC), "vehicles": {}}
    for sysid in vehicles:
        report["vehicles"][f"v{sysid}"] = {
            leaf: board.latest.get(vehicle_topic(sysid, leaf))
            for leaf in ("attack/state", "attack/mode/state", "secure/state", "stats")
        }
    if args.json:
        print(json.dumps(report, indent=2))
        return EXIT_OK
    print(f"proxy: {_online(board)}")
    for key, entry in report["vehicles"].items():
        attack = entry["attack/state"] or {}
        active = f"{attack.get('profile')} (hash {str(attack.get('hash'))[:12]})" if attack.get("profile") else "none"
        last = "ok" if attack.get("ok") else f"rejected: {attack.get('error')}"
        mode = (entry["attack/mode/state"] or {}).get("mode")
        bypass = " (bypassed)" if mode == "bypass" else ""
        print(f"{key}: attack {active}{bypass} since {_since(attack.get('since'))}; last request {last}")
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
    leaves = ("attack/state", "attack/mode/state", "secure/state", "stats")
    topics = [*(f"{PREFIX}/+/{leaf}" for leaf in leaves), ONLINE_TOPIC]
    return _session(args, topics, lambda c, b, a: _status(b, args))


def main(argv: Sequence[str] | None = None) -> int:
    return profiles_cli.main(
        argv,
        live_handlers={"apply": cmd_apply, "clear": cmd_clear, "status": cmd_status, "mode": cmd_mode,
                       "secure": cmd_secure},
        live_options=add_options,
    )


if __name__ == "__main__":
    sys.exit(main())

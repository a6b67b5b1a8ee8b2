"""``secuav-attack``: check, list, show and export attack profiles.

Offline subcommands live here: ``validate F [--scenario S]``, ``list``,
``show NAME``, ``schema``. ``status`` and each runtime switch's verbs (``apply``,
``clear``, ``mode``, ``secure``, ``routes``: declared with their switch in
``secuav_common/controlplane/switches/``) talk to a running proxy; their parsers
are built here so the proxy's CLI (``mitm_proxy.tools.attack_cli``, the installed
``secuav-attack``) can reuse :func:`build_parser` and plug in real handlers
through ``live_handlers`` and its transport flags through ``live_options`` (this
module alone answers them with one line saying so and exit 2: a library never
imports the service).

Every failure is one line on stderr and a non-zero exit code; no traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from attack_profiles import library
from attack_profiles.directions import describe, directions_of
from attack_profiles.engine import Engine
from attack_profiles.profile import Profile, profile_schema_text
from attack_profiles.quantities import true_copies
from attack_profiles.resolve import resolve_profile
from attack_profiles.true_copy import vehicle_reports
from secuav_common.controlplane import switches
from secuav_common.loading import InputError, parse_params
from secuav_common.logs import add_common_flags
from secuav_common.scenario import load_scenario

Handler = Callable[[argparse.Namespace], int]
OptionsHook = Callable[[str, argparse.ArgumentParser], None]  # (subcommand, its parser): add transport options
VEHICLE_HELP = "only this vehicle's sysid"


def live_commands() -> list[str]:
    """Every subcommand that needs a running proxy: ``status`` and each switch's verbs."""
    return ["status", *(verb.name for _, verb in switches.verbs())]


def _params(pairs: Sequence[str]) -> dict[str, Any]:
    return parse_params(pairs)


def _resolve(ref: str, params: dict[str, Any]) -> Profile:
    return resolve_profile(ref, params, "profile")


def cmd_validate(args: argparse.Namespace) -> int:
    profile = _resolve(args.profile, _params(args.param))
    where = ""
    if args.scenario:
        scenario = load_scenario(args.scenario)
        Engine(profile, scenario=scenario)  # checks sensor ids and builds every rule
        where = f", fits scenario {scenario.name!r}"
    elif not _needs_scenario(profile):
        Engine(profile)  # builds every rule, as the proxy will
    print(f"ok: {profile.name} ({len(profile.rules)} rules, hash {profile.content_hash()[:12]}{where}; "
          f"changes frames {describe(directions_of(profile))})")
    for warning in true_copies(profile):  # valid, but a true copy of the attacked value may stay on the wire
        print(f"warning: {warning}", file=sys.stderr)
    for note in vehicle_reports(profile):  # toward the vehicle: the autopilot reports the lie itself
        print(f"note: {note}", file=sys.stderr)
    return 0


def _needs_scenario(profile: Profile) -> bool:
    return any(r.kind == "coordinated_spoof" for r in profile.rules)


def cmd_list(args: argparse.Namespace) -> int:
    entries = library.describe()
    bundled = set(library.names(plugins=False))
    width = max(len(name) for name, _ in entries)
    for name, description in entries:
        source = "" if name in bundled else " [from {} {}]".format(*library.origin(name))
        print(f"{name:<{width}}  {description}{source}")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    if args.param:
        profile = library.load(args.name, **_params(args.param))
        print(json.dumps(profile.model_dump(mode="json"), indent=2))
    else:
        sys.stdout.write(library.text(args.name))
    return 0


def cmd_schema(args: argparse.Namespace) -> int:
    sys.stdout.write(profile_schema_text(plugins=True))  # what this installation accepts, plugins included
    return 0


def needs_proxy(args: argparse.Namespace) -> int:
    print(
        f"secuav-attack {args.command}: needs a running proxy; this arrives with the proxy issue "
        "(offline: validate, list, show, schema)",
        file=sys.stderr,
    )
    return 2


def build_parser(
    live_handlers: Mapping[str, Handler] | None = None, live_options: OptionsHook | None = None
) -> argparse.ArgumentParser:
    """The full command line; ``live_handlers`` maps ``status`` and the switches' verbs to real
    implementations and ``live_options`` adds the options they need (broker, timeout) to those subcommands."""
    live = dict.fromkeys(live_commands(), needs_proxy)
    live.update(live_handlers or {})
    parser = argparse.ArgumentParser(prog="secuav-attack", description="Check, list and apply SecUAV attack profiles.")
    add_common_flags(parser, log_flags=False)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("validate", help="check a profile file (or library name) offline")
    p.add_argument("profile", metavar="F", help="profile file (YAML/JSON) or library name")
    p.add_argument("--scenario", metavar="S", help="also check sensor ids against this scenario (file or bundled name)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="override a profile parameter")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("list", help="the library of ready profiles, one line each")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("show", help="print a library profile")
    p.add_argument("name", metavar="NAME")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="print it resolved, as JSON")
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("schema", help="print the profile JSON Schema")
    p.set_defaults(func=cmd_schema)

    p = sub.add_parser("status", help="show the active profile of a running proxy")
    p.add_argument("--vehicle", type=int, metavar="N", help=VEHICLE_HELP)
    p.set_defaults(func=live["status"])
    targets: dict[str, tuple[argparse.ArgumentParser, ...]] = {"status": (p,)}

    for spec, verb in switches.verbs():
        p = sub.add_parser(verb.name, help=verb.help)
        if spec.scope == "vehicle":  # sent to one vehicle, or to every vehicle on the broker
            verb.arguments(p)
            p.add_argument("--vehicle", type=int, metavar="N", help=VEHICLE_HELP)
            targets[verb.name] = (p,)
        else:  # proxy-wide: read one instance's state, or send it a request
            actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
            show = actions.add_parser("show", help=verb.show_help)
            change = actions.add_parser("set", help=verb.set_help)
            verb.arguments(change)
            targets[verb.name] = (show, change)
        for q in targets[verb.name]:
            if spec.scope == "proxy":
                q.add_argument("--instance", metavar="NAME", help="the proxy instance (needed when several are online)")
            q.set_defaults(func=live[verb.name])

    if live_options is not None:
        for name, parsers in targets.items():
            for q in parsers:
                live_options(name, q)
    return parser


def main(
    argv: Sequence[str] | None = None,
    live_handlers: Mapping[str, Handler] | None = None,
    live_options: OptionsHook | None = None,
) -> int:
    args = build_parser(live_handlers, live_options).parse_args(argv)
    try:
        return int(args.func(args))
    except InputError as err:
        print(f"secuav-attack: {err}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `secuav-attack list | head`
        return 0


if __name__ == "__main__":
    sys.exit(main())

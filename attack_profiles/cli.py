"""``secuav-attack``: check, list, show and export attack profiles.

Offline subcommands live here: ``validate F [--scenario S]``, ``list``,
``show NAME``, ``schema``. ``status`` and each runtime switch's verbs (``apply``,
``clear``, ``mode``, ``secure``, ``routes``) talk to a running proxy: the proxy's
CLI (``mitm_proxy.tools.attack_cli``, the installed ``secuav-attack``) owns them
and adds them to :func:`build_parser` through its ``live`` hook (a library never
imports the service).

Every failure is one line on stderr and a non-zero exit code; no traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from typing import Any

from attack_profiles import library
from attack_profiles.directions import describe, directions_of
from attack_profiles.engine import Engine
from attack_profiles.profile import Profile, profile_schema_text
from attack_profiles.resolve import resolve_profile
from attack_profiles.true_copy import true_copies, vehicle_reports
from secuav_common.loading import InputError, parse_params
from secuav_common.logs import add_common_flags
from secuav_common.scenario import load_scenario

Handler = Callable[[argparse.Namespace], int]
LiveHook = Callable[[Any], None]  # adds the subcommands that need a running proxy to the subparsers it is given


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


def build_parser(live: LiveHook | None = None) -> argparse.ArgumentParser:
    """The command line: the offline subcommands, then what ``live`` adds (``status`` and the switches'
    verbs, from ``mitm_proxy.tools.attack_cli``)."""
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

    if live is not None:
        live(sub)
    return parser


def main(argv: Sequence[str] | None = None, live: LiveHook | None = None) -> int:
    args = build_parser(live).parse_args(argv)
    try:
        return int(args.func(args))
    except InputError as err:
        print(f"secuav-attack: {err}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `secuav-attack list | head`
        return 0


if __name__ == "__main__":
    sys.exit(main())

"""``secuav-attack routes show|set``: the ``routes`` switch's verb (the rules' grammar: docs/routes.md)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from mitm_proxy.net.rules import EndpointRules, rules_from_query, rules_to_query
from mitm_proxy.tools.verbs.base import State, SwitchVerbs, Verb
from secuav_common.controlplane.switches.routes import CONTRACT


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("endpoint", metavar="ENDPOINT", help="as the stats name it (ground:14550) or its URL")
    parser.add_argument(
        "rules",
        metavar="RULES",
        help="URL options as in docs/routes.md ('deny=ATTITUDE&listen_only=true'); 'none' lifts all",
    )


def _lifts_all(args: argparse.Namespace) -> bool:
    return bool(args.rules.strip().lower() in ("none", ""))


def _request(args: argparse.Namespace) -> dict[str, Any]:
    """The rules checked here first, as the proxy will check them (a typo fails before anything is sent)."""
    if _lifts_all(args):
        return {"endpoints": {args.endpoint: None}}
    rules = rules_from_query(args.rules, "RULES").model_dump(exclude_defaults=True)
    return {"endpoints": {args.endpoint: rules}}


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} {args.endpoint} {'no rules' if _lifts_all(args) else args.rules}"


def _show(name: str, state: State) -> list[str]:
    lines = [f"proxy {name}:"]
    for ep_name, ep in (state.get("endpoints") or {}).items():
        try:
            spelled = rules_to_query(EndpointRules.model_validate(ep.get("rules") or {})) or "no rules"
        except ValueError:
            spelled = json.dumps(ep.get("rules"))
        lines.append(f"  {ep_name:<16} {ep.get('role', '?'):<7} {ep.get('url')}  {spelled}")
    return lines


VERBS = SwitchVerbs(CONTRACT, (Verb("routes", "show or change a running proxy's per-endpoint routing rules",
                                   _done, _arguments, _request, show=_show,
                                   show_help="every endpoint of the proxy and its rules",
                                   set_help="replace one endpoint's rules (the others keep theirs)"),))  # fmt: skip

"""``routes``: the endpoints' routing rules of one proxy (``secuav/proxy/[<instance>/]routes/set``).

Proxy-wide: a request on ``secuav/proxy/routes/set`` reaches every proxy, one on
``secuav/proxy/<instance>/routes/set`` that instance; each answers on its own
``secuav/proxy/<instance>/routes/state``. The proxy's side is
:class:`mitm_proxy.control.switches.RoutesSwitch`; the rules' grammar is the proxy's
(``mitm_proxy/net/rules.py``, docs/routes.md), imported when ``secuav-attack routes`` runs.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from secuav_common.controlplane.payloads import RoutesState
from secuav_common.controlplane.switches import State, SwitchSpec, Verb, register


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
    from mitm_proxy.net.rules import rules_from_query

    rules = rules_from_query(args.rules, "RULES").model_dump(exclude_defaults=True)
    return {"endpoints": {args.endpoint: rules}}


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} {args.endpoint} {'no rules' if _lifts_all(args) else args.rules}"


def _show(name: str, state: State) -> list[str]:
    from mitm_proxy.net.rules import EndpointRules, rules_to_query

    lines = [f"proxy {name}:"]
    for ep_name, ep in (state.get("endpoints") or {}).items():
        try:
            spelled = rules_to_query(EndpointRules.model_validate(ep.get("rules") or {})) or "no rules"
        except ValueError:
            spelled = json.dumps(ep.get("rules"))
        lines.append(f"  {ep_name:<16} {ep.get('role', '?'):<7} {ep.get('url')}  {spelled}")
    return lines


SPEC = register(SwitchSpec(
    kind="routes",
    scope="proxy",
    state_model=RoutesState,
    implementation="mitm_proxy.control.switches:RoutesSwitch.build",
    verbs=(Verb("routes", "show or change a running proxy's per-endpoint routing rules", _done, _arguments,
                _request, show=_show, show_help="every endpoint of the proxy and its rules",
                set_help="replace one endpoint's rules (the others keep theirs)"),),
))  # fmt: skip

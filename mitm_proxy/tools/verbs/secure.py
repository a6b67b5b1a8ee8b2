"""``secuav-attack secure NAME|off``: the ``secure`` switch's verb, and its ``status`` line."""

from __future__ import annotations

import argparse
from typing import Any

from attack_profiles.resolve import parse_params
from mitm_proxy.tools.verbs.base import State, SwitchVerbs, Verb
from secuav_common.controlplane.switches.secure import CONTRACT


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("estimator", metavar="NAME",
                        help="secekf, secopt, recap, rarse, l1, l0, milp, ekf, ls, a plugin's name (secuav-plugins), "
                        "package.module:Class, or off")  # fmt: skip
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="estimator parameter")
    parser.add_argument("--direction", choices=("downlink", "uplink", "both"),
                        help="where the stage reads its group and substitutes: downlink (toward the ground), "
                        "uplink (the frames the autopilot receives) or both; left out: as it is")  # fmt: skip


def _request(args: argparse.Namespace) -> dict[str, Any]:
    body: dict[str, Any] = {"estimator": args.estimator}
    if args.param:
        body["params"] = parse_params(args.param)
    if getattr(args, "direction", None) is not None:
        body["direction"] = args.direction
    return body


# SecureState.direction in words: which frames the stage reads and rewrites.
_ON = {"downlink": "toward the ground", "uplink": "toward the vehicle", "both": "in both directions"}


def _where(state: State) -> str:
    direction = state.get("direction")
    return f" on the frames {_ON[direction]}" if state.get("estimator") and direction in _ON else ""


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} secure {state.get('estimator') or 'off'}{_where(state)}"


def _status(key: str, states: dict[str, State | None]) -> list[str]:
    secure = states.get("secure/state")
    if not isinstance(secure, dict):
        return []
    if secure.get("available") is False:
        return [f"{key}: secure not available in this proxy"]
    note = "" if secure.get("ok") else f"; last request rejected: {secure.get('error')}"
    return [f"{key}: secure {secure.get('estimator') or 'off'}{_where(secure)}{note}"]


VERBS = SwitchVerbs(CONTRACT, (Verb("secure", "choose the secure stage's estimator on a running proxy, or 'off'",
                                   _done, _arguments, _request),), status=_status)  # fmt: skip

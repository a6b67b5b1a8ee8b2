"""``secuav-attack apply F`` and ``clear``: the ``attack`` switch's verbs.

``apply`` checks the profile here first (a typo fails at once, with the file and field named) and sends it
resolved; ``clear`` sends ``null``.
"""

from __future__ import annotations

import argparse
import json
import uuid
from typing import Any

from attack_profiles.resolve import parse_params, resolve_profile
from mitm_proxy.tools.verbs.base import State, SwitchVerbs, Verb, since_text
from secuav_common.controlplane.payloads import MAX_PAYLOAD_BYTES, request_bytes
from secuav_common.controlplane.switches.attack import CONTRACT
from secuav_common.loading import InputError


def _apply_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("profile", metavar="F", help="profile file (YAML/JSON) or library name")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override a profile parameter")  # fmt: skip


def _apply_request(args: argparse.Namespace) -> dict[str, Any]:
    profile = resolve_profile(args.profile, parse_params(args.param), "profile")
    body: dict[str, Any] = json.loads(profile.canonical_json())
    size = len(request_bytes(body, uuid.uuid4().hex))
    if size > MAX_PAYLOAD_BYTES:
        raise InputError(args.profile, "", size, f"the proxy accepts profiles up to {MAX_PAYLOAD_BYTES} bytes of JSON")
    return body


# The wire names of AttackState.directions in words.
_WORDS = {"downlink": "toward the ground", "uplink": "toward the vehicle"}


def _toward(directions: Any) -> str:
    """``toward the ground``, ``toward the vehicle``, both joined, ``nothing``; ``?`` from an older proxy."""
    if not isinstance(directions, list):
        return "(directions unknown)"
    words = [_WORDS[d] for d in _WORDS if d in directions]
    return " and ".join(words) if words else "nothing"


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    if state.get("profile") is None:
        return f"ok: {key} cleared"
    return (f"ok: {key} {state['profile']} (hash {str(state.get('hash'))[:12]}), "
            f"changing frames {_toward(state.get('directions'))}")  # fmt: skip


def _status(key: str, states: dict[str, State | None]) -> list[str]:
    attack = states.get("attack/state") or {}
    active = f"{attack.get('profile')} (hash {str(attack.get('hash'))[:12]})" if attack.get("profile") else "none"
    if attack.get("profile"):
        active += f" changing frames {_toward(attack.get('directions'))}"
    last = "ok" if attack.get("ok") else f"rejected: {attack.get('error')}"
    bypass = " (bypassed)" if (states.get("attack/mode/state") or {}).get("mode") == "bypass" else ""
    return [f"{key}: attack {active}{bypass} since {since_text(attack.get('since'))}; last request {last}"]


VERBS = SwitchVerbs(
    CONTRACT,
    (Verb("apply", "activate a profile on a running proxy", _done, _apply_arguments, _apply_request),
     Verb("clear", "remove the active profile on a running proxy", _done)),
    status=_status,
)  # fmt: skip

"""``secuav-attack mode on|bypass``: the ``attack/mode`` switch's verb (``status`` shows a bypassed stage on
the ``attack`` line)."""

from __future__ import annotations

import argparse

from mitm_proxy.tools.verbs.base import State, SwitchVerbs, Verb
from secuav_common.controlplane.payloads import MODES
from secuav_common.controlplane.switches.mode import CONTRACT


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mode", choices=list(MODES))


def _request(args: argparse.Namespace) -> dict[str, str]:
    return {"mode": args.mode}


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} attack {state.get('mode')}"


VERBS = SwitchVerbs(CONTRACT, (Verb("mode", "switch the attack stage on or to bypass (the profile stays installed)",
                                   _done, _arguments, _request),))  # fmt: skip

"""``attack/mode``: the attack stage on, or bypassed with its profile kept (``secuav/v<N>/attack/mode/set``).

The proxy's side is :class:`mitm_proxy.control.switches.ModeSwitch`, which writes the attack stage's
``enabled`` flag; ``secuav-attack status`` shows a bypassed stage on the ``attack`` line.
"""

from __future__ import annotations

import argparse

from secuav_common.controlplane.payloads import ModeState
from secuav_common.controlplane.switches import State, SwitchSpec, Verb, register

MODES = ("on", "bypass")


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mode", choices=list(MODES))


def _request(args: argparse.Namespace) -> dict[str, str]:
    return {"mode": args.mode}


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} attack {state.get('mode')}"


SPEC = register(SwitchSpec(
    kind="attack/mode",
    scope="vehicle",
    state_model=ModeState,
    implementation="mitm_proxy.control.switches:ModeSwitch.build",
    verbs=(Verb("mode", "switch the attack stage on or to bypass (the profile stays installed)",
                _done, _arguments, _request),),
    bare_words=frozenset(m.encode() for m in MODES),
))  # fmt: skip

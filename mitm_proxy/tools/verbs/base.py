"""What one switch's command line is: its verbs (:class:`Verb`) and its ``status`` lines (:class:`SwitchVerbs`)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.topics import Scope

__all__ = ["State", "SwitchVerbs", "Verb", "since_text"]

State = dict[str, Any]  # a state as plain JSON, as the CLI reads it


def _no_arguments(parser: argparse.ArgumentParser) -> None:
    return None


def _no_request(args: argparse.Namespace) -> Any:
    return None


@dataclass(frozen=True, slots=True)
class Verb:
    """One ``secuav-attack`` subcommand that sends a request to a switch and waits for its verdict.

    ``arguments`` adds the subcommand's own arguments (the CLI adds ``--vehicle``,
    or ``--instance`` and the ``show``/``set`` actions for a proxy-wide switch, and
    the transport options); ``request(args)`` builds what is sent (``None``: a bare
    request, such as clear), checked here first, so a bad value fails with exit 1
    before the broker is involved; ``done(key, state, args)`` is the line printed
    for an accepted state (``key`` is ``v<N>`` or the instance name).
    """

    name: str
    help: str
    done: Callable[[str, State, argparse.Namespace], str]
    arguments: Callable[[argparse.ArgumentParser], None] = _no_arguments
    request: Callable[[argparse.Namespace], Any] = _no_request
    # A proxy-wide switch's verb has two actions, ``show`` (its state on one instance, or every one with
    # ``--json``) and ``set`` (these arguments, this request); ``show`` prints the lines for one instance.
    show: Callable[[str, State], list[str]] | None = None
    show_help: str = "the state of one proxy"
    set_help: str = "send a request"


@dataclass(frozen=True, slots=True)
class SwitchVerbs:
    """The command line of one switch: its contract, its verbs, and its ``status`` lines of one vehicle
    (``status(key, every switch state of that vehicle by "<kind>/state")``; None: it adds none)."""

    contract: SwitchContract
    verbs: tuple[Verb, ...] = ()
    status: Callable[[str, dict[str, State | None]], list[str]] | None = None

    @property
    def kind(self) -> str:
        return self.contract.kind

    @property
    def scope(self) -> Scope:
        return self.contract.scope

    @property
    def state_leaf(self) -> str:
        return self.contract.state_leaf


def since_text(epoch_s: Any) -> str:
    """A state's ``since`` (epoch s) as the CLI prints it."""
    if not isinstance(epoch_s, int | float):
        return "-"
    return datetime.fromtimestamp(epoch_s, UTC).strftime("%Y-%m-%d %H:%M:%SZ")

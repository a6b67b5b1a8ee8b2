"""The runtime switches, one module each, and the registry everything else iterates.

A switch is declared once, in ``secuav_common/controlplane/switches/<name>.py``,
as a :class:`SwitchSpec`:

- ``kind``, the topic leaf (``secuav/v<N>/<kind>/set`` and ``.../state``), and
  ``scope``: ``vehicle`` (one per link) or ``proxy`` (one per process, on
  ``secuav/proxy/[<instance>/]<kind>/...``);
- ``state_model``, what ``.../state`` carries, and optionally ``request_model``,
  what ``.../set`` must hold (the proxy checks it before the switch sees it);
- ``implementation``, where the proxy's side lives (``"module:factory"``, imported
  only by the proxy, so consumers never load it): a callable
  ``(host, sysid) -> Switch | None`` that builds, or finds, the switch of one
  vehicle (``sysid`` None for a proxy-wide switch);
- ``verbs``: its ``secuav-attack`` subcommands (:class:`Verb`: arguments, the
  request they send, the line printed for an accepted state, the lines ``status``
  prints).

The module ends with ``register(SPEC)``; :func:`specs` imports every module of
this package, so a new switch is a new file here (plus its implementation and its
row in docs/interfaces.md), and the proxy's registry
(:mod:`mitm_proxy.control.switches`), its MQTT session, payload checking
(:func:`secuav_common.controlplane.payloads.model_for`) and ``secuav-attack`` pick it up.

This package needs pydantic and the topic grammar only: the console and
``secuav-attack`` import the models without the proxy.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from pydantic import BaseModel

from secuav_common.controlplane.topics import Scope

__all__ = ["State", "SwitchSpec", "Verb", "find", "register", "since_text", "spec_for", "specs", "unregister", "verbs"]

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
class SwitchSpec:
    """Everything about one runtime switch that is not the proxy's own code (see the module docstring)."""

    kind: str
    scope: Scope
    state_model: type[BaseModel]
    implementation: str  # "package.module:factory" (dots after the colon reach an attribute: "Class.build")
    verbs: tuple[Verb, ...] = ()
    request_model: type[BaseModel] | None = None
    bare_words: frozenset[bytes] = frozenset()  # accepted without JSON quotes (``mosquitto_pub -m off``)
    status: Callable[[str, dict[str, State | None]], list[str]] | None = None  # ``status`` lines of one vehicle
    # (its key, every switch state of that vehicle by "<kind>/state"); None: the switch adds none

    @property
    def state_leaf(self) -> str:
        return f"{self.kind}/state"

    def load(self) -> Callable[..., Any]:
        """The proxy-side factory (imported now, not before: it may pull in numpy, the stages...)."""
        module, _, attr = self.implementation.partition(":")
        target: Any = importlib.import_module(module)
        for part in attr.split("."):
            target = getattr(target, part)
        return target  # type: ignore[no-any-return]


_REGISTRY: dict[str, SwitchSpec] = {}
_DISCOVERED = False


def register(spec: SwitchSpec) -> SwitchSpec:
    """Add ``spec`` (a switch's module calls this on import); a kind or verb registered twice is a bug."""
    _discover()  # the built-ins first, so a clash with one of them is seen whoever registers first
    old = _REGISTRY.get(spec.kind)
    if old is not None and old is not spec:
        raise ValueError(f"switch {spec.kind!r} is registered twice")
    taken = {v.name for s in _REGISTRY.values() if s.kind != spec.kind for v in s.verbs}
    clash = sorted(taken & {v.name for v in spec.verbs})
    if clash:
        raise ValueError(f"switch {spec.kind!r}: verb {clash[0]!r} belongs to another switch")
    _REGISTRY[spec.kind] = spec
    return spec


def unregister(kind: str) -> None:
    """Take a switch out again (tests that declare one of their own)."""
    _REGISTRY.pop(kind, None)


def _discover() -> None:
    global _DISCOVERED
    if not _DISCOVERED:
        _DISCOVERED = True  # first: the modules imported below register, which comes back here
        for module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
            importlib.import_module(f"{__name__}.{module}")


def specs() -> list[SwitchSpec]:
    """Every switch: the vehicle ones first, then the proxy-wide ones, each by kind."""
    _discover()
    return sorted(_REGISTRY.values(), key=lambda s: (s.scope != "vehicle", s.kind))


def find(scope: str, kind: str) -> SwitchSpec | None:
    """The switch a topic's scope and leaf name, if any."""
    _discover()
    spec = _REGISTRY.get(kind)
    return spec if spec is not None and spec.scope == scope else None


def spec_for(verb_name: str) -> tuple[SwitchSpec, Verb] | None:
    """The switch that owns a ``secuav-attack`` verb."""
    return next(((s, v) for s, v in verbs() if v.name == verb_name), None)


def verbs() -> Iterator[tuple[SwitchSpec, Verb]]:
    """Every ``secuav-attack`` verb with its switch, in :func:`specs` order."""
    for spec in specs():
        for verb in spec.verbs:
            yield spec, verb


def since_text(epoch_s: Any) -> str:
    """A state's ``since`` (epoch s) as the CLI prints it."""
    if not isinstance(epoch_s, int | float):
        return "-"
    return datetime.fromtimestamp(epoch_s, UTC).strftime("%Y-%m-%d %H:%M:%SZ")

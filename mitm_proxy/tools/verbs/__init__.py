"""The runtime switches' ``secuav-attack`` verbs: one small module per switch, and the tuple that lists them.

Each module declares, for one switch contract (``secuav_common/controlplane/switches/``),
its :class:`Verb` s (arguments, the request they send, the line printed for an
accepted state) and the lines ``status`` prints, as a :class:`SwitchVerbs`.
:mod:`mitm_proxy.tools.attack_cli` builds the parser from :func:`switches` and
runs any of them the same way. :data:`BUILT_IN` is the explicit list; :func:`register`
adds one more by an explicit call (a test's switch, a lab's own).
"""

from __future__ import annotations

from collections.abc import Iterator

from mitm_proxy.tools.verbs import attack, mode, routes, secure
from mitm_proxy.tools.verbs.base import State, SwitchVerbs, Verb, since_text
from secuav_common.registry import Registry

__all__ = ["BUILT_IN", "State", "SwitchVerbs", "Verb", "owner", "register", "since_text", "switches", "unregister",
           "verbs"]  # fmt: skip


BUILT_IN: tuple[SwitchVerbs, ...] = (attack.VERBS, mode.VERBS, secure.VERBS, routes.VERBS)
TABLE: Registry[SwitchVerbs] = Registry("switch")
for _entry in BUILT_IN:
    TABLE.register(_entry.kind, _entry)


def register(entry: SwitchVerbs) -> SwitchVerbs:
    """Add the verbs of a switch that is not built in; a kind or a verb name taken twice is a bug."""
    taken = {v.name for s in switches() if s.kind != entry.kind for v in s.verbs}
    clash = sorted(taken & {v.name for v in entry.verbs})
    if clash:
        raise ValueError(f"switch {entry.kind!r}: verb {clash[0]!r} belongs to another switch")
    return TABLE.add(entry.kind, entry)


def unregister(kind: str) -> None:
    """Take an added switch's verbs out again (tests that declare one of their own)."""
    TABLE.remove(kind)


def switches() -> list[SwitchVerbs]:
    """Every switch's command line: the vehicle ones first, then the proxy-wide ones, each by kind."""
    return sorted(TABLE.table.values(), key=lambda s: (s.scope != "vehicle", s.kind))


def verbs() -> Iterator[tuple[SwitchVerbs, Verb]]:
    """Every ``secuav-attack`` verb with its switch, in :func:`switches` order."""
    for entry in switches():
        for verb in entry.verbs:
            yield entry, verb


def owner(verb_name: str) -> tuple[SwitchVerbs, Verb] | None:
    """The switch that owns a ``secuav-attack`` verb."""
    return next(((s, v) for s, v in verbs() if v.name == verb_name), None)

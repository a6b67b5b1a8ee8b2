"""The runtime switches' wire contracts: one small module each, and the one tuple that lists them.

Each module declares one :class:`~secuav_common.controlplane.contract.SwitchContract`
(``CONTRACT``): its topic leaf, scope, state and request models, bare words. The
proxy's side of each (``mitm_proxy/control/``) and its ``secuav-attack`` verbs
(``mitm_proxy/tools/verbs/``) live with their own audiences and name this contract;
a test keeps the three lists of kinds equal.

:data:`BUILT_IN` is the explicit list; :func:`register` adds one more kind (a
test's, a lab's own) by an explicit call. Payload checks
(:func:`secuav_common.controlplane.payloads.model_for`), the console and
``secuav-attack`` find a contract through :func:`find` and :func:`contracts`.
"""

from __future__ import annotations

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.switches import attack, mode, routes, secure
from secuav_common.registry import Registry

__all__ = ["BUILT_IN", "SwitchContract", "contracts", "find", "register", "unregister"]

BUILT_IN: tuple[SwitchContract, ...] = (attack.CONTRACT, mode.CONTRACT, secure.CONTRACT, routes.CONTRACT)
TABLE: Registry[SwitchContract] = Registry("switch")  # the same shape as the estimators' and primitives' tables
for _contract in BUILT_IN:
    TABLE.register(_contract.kind, _contract)


def register(contract: SwitchContract) -> SwitchContract:
    """Add a switch that is not built in; a kind declared twice is a bug."""
    return TABLE.add(contract.kind, contract)


def unregister(kind: str) -> None:
    """Take an added switch out again (tests that declare one of their own)."""
    TABLE.remove(kind)


def contracts() -> list[SwitchContract]:
    """Every switch: the vehicle ones first, then the proxy-wide ones, each by kind."""
    return sorted(TABLE.table.values(), key=lambda c: (c.scope != "vehicle", c.kind))


def find(scope: str, kind: str) -> SwitchContract | None:
    """The switch a topic's scope and leaf name, if any."""
    return next((c for c in contracts() if c.kind == kind and c.scope == scope), None)

"""What the proxy holds for one link (its stage and the switches that wrap it), and for the whole process."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.mode import ModeSwitch
from mitm_proxy.control.secure import NoSecure, SecureSwitch
from mitm_proxy.control.switch import Switch
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage

if TYPE_CHECKING:
    from mitm_proxy.net.endpoints import BaseEndpoint

__all__ = ["LinkParts", "SwitchHost"]


@dataclass(slots=True)
class LinkParts:
    """One link (one vehicle): its attack stage and the switches that wrap it, its counters, and its secure
    switch (with its stage) where a scenario models the sensors."""

    sysid: int
    stage: AttackStage
    attack: AttackSwitch
    mode: ModeSwitch
    stats: LinkStats
    secure: SecureSwitch | None = None

    def switches(self) -> list[Switch[Any]]:
        """The link's switches, as the registry serves them: a link without a secure stage (no scenario) has
        a ``secure`` switch that refuses every request, saying why."""
        return [self.attack, self.mode, self.secure if self.secure is not None else NoSecure(self.sysid)]


@dataclass(frozen=True, slots=True)
class SwitchHost:
    """What the registry builds on: this process's instance name, its links by sysid, its endpoints by name
    (a switch the links do not hold, such as ``routes``, is built from it: ``build(host, sysid)``)."""

    instance: str
    links: Mapping[int, LinkParts]
    endpoints: Mapping[str, BaseEndpoint] = field(default_factory=dict)

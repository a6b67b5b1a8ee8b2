"""What the proxy holds for one link, and for the whole process, as the switches' factories find it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage

if TYPE_CHECKING:
    from mitm_proxy.control.attack import AttackSwitch
    from mitm_proxy.control.mode import ModeSwitch
    from mitm_proxy.control.secure import SecureSwitch
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


@dataclass(frozen=True, slots=True)
class SwitchHost:
    """What a switch's :meth:`~mitm_proxy.control.switch.Switch.build` may build on: this process's instance
    name, its links by sysid, its endpoints by name."""

    instance: str
    links: Mapping[int, LinkParts]
    endpoints: Mapping[str, BaseEndpoint] = field(default_factory=dict)

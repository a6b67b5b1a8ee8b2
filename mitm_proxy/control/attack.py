"""The ``attack`` switch: which profile the link's attack stage runs (``secuav/v<N>/attack/set``).

It wraps the stage's :class:`~mitm_proxy.stages.attack_slot.AttackSlot` (the
holder the stage reads at every targeted frame): the slot builds and installs,
the switch keeps the verdict. ``secuav-attack apply F`` checks the profile first
and sends it resolved; ``clear`` sends ``null``.
"""

from __future__ import annotations

from typing import Any

from attack_profiles.engine import Engine
from attack_profiles.profile import Profile
from mitm_proxy.control.switch import Switch
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.controlplane.payloads import AttackState
from secuav_common.controlplane.switches.attack import CONTRACT, AttackRequest
from secuav_common.controlplane.topics import vehicle_topic

__all__ = ["AttackSwitch"]


def _plain(payload: Any) -> Any:
    return payload.root if isinstance(payload, AttackRequest) else payload


class AttackSwitch(Switch[AttackState]):
    """The active profile of one link: a profile, its JSON, a library reference, ``None`` to clear, or an
    engine built by the caller (``secuav-record`` shares one clock among the vehicles)."""

    contract = CONTRACT

    def __init__(self, slot: AttackSlot) -> None:
        super().__init__()
        self.slot = slot
        self.sysid = slot.sysid

    @property
    def engine(self) -> Engine | None:
        """The engine in force (what the attack stage runs)."""
        return self.slot.engine

    def prepare(self, payload: Any, source: str) -> Any:
        return self.slot.prepare(_plain(self._checked(payload)), source)

    def apply(self, payload: Any, source: str) -> None:
        self.slot.apply(_plain(payload), source)

    def current(self) -> dict[str, Any]:
        return self.slot.current()

    def _log_fields(self) -> dict[str, Any]:
        return self.slot.log_fields()

    def offer(self, profile: Profile | None, request_id: str | None = None, source: str = "<profile>") -> AttackState:
        """Install ``profile`` (``None`` clears); on ``InputError`` keep the old one and report it."""
        return self.handle(profile, request_id, source)

    def offer_payload(self, payload: Any, request_id: str | None = None, source: str | None = None) -> AttackState:
        """Decoded JSON of an ``attack/set`` message: a profile, ``{"library": ...}`` or ``null``."""
        return self.handle(payload, request_id, source or vehicle_topic(self.sysid, "attack", "set"))

    def install(self, engine: Engine, request_id: str | None = None) -> AttackState:
        """An engine the caller built and activated (its clock shared with other slots)."""
        return self.handle(engine, request_id, "<engine>")

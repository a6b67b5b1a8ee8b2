"""The per-link holder of the active attack profile.

Every way of changing the profile (``--profile`` at start, the file reload, MQTT
``secuav/v<sysid>/attack/set``, ``secuav-attack apply``) goes through
:meth:`AttackSlot.offer`; the attack stage reads :attr:`AttackSlot.engine` once
per targeted frame. A new engine is built and checked completely before the
single attribute assignment that installs it, and the event loop runs one
callback at a time, so a swap always falls between two frames. A rejected
profile leaves the previous engine in place and says why in :attr:`state`.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

from attack_profiles.control import profile_from_payload
from attack_profiles.engine import Engine
from attack_profiles.profile import Profile
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario


@dataclass(frozen=True, slots=True)
class SlotState:
    """What ``secuav/v<sysid>/attack/state`` carries (retained)."""

    sysid: int
    profile: str | None  # active profile name; None when no profile is active
    hash: str | None
    since: float | None  # wall-clock time (epoch s) the active profile was installed
    request_id: str | None  # of the last request, accepted or not
    ok: bool  # whether the last request was accepted
    error: str | None  # why it was rejected

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


class AttackSlot:
    """Active profile of one link (one vehicle)."""

    def __init__(self, sysid: int, scenario: Scenario | None = None, seed: int = 0) -> None:
        self.sysid = sysid
        self.scenario = scenario
        self.seed = seed
        self.engine: Engine | None = None
        self.state = SlotState(sysid, None, None, None, None, True, None)

    @property
    def message_ids(self) -> frozenset[int]:
        return self.engine.message_ids if self.engine is not None else frozenset()

    def offer(self, profile: Profile | None, request_id: str | None = None) -> SlotState:
        """Install ``profile`` (``None`` clears); on ``InputError`` keep the old one and report it."""
        try:
            engine = None if profile is None else Engine(profile, self.seed, self.scenario)
        except InputError as exc:
            return self._reject(str(exc), request_id)
        if engine is not None:
            engine.activate(time.monotonic())
        self.engine = engine
        self.state = SlotState(
            sysid=self.sysid,
            profile=None if profile is None else profile.name,
            hash=None if profile is None else profile.content_hash(),
            since=time.time(),
            request_id=request_id,
            ok=True,
            error=None,
        )
        return self.state

    def offer_payload(self, payload: Any, request_id: str | None = None, source: str = "<mqtt>") -> SlotState:
        """Decoded JSON of an ``attack/set`` message: a profile, ``{"library": ...}`` or ``null``."""
        try:
            profile = profile_from_payload(payload, source)
        except InputError as exc:
            return self._reject(str(exc), request_id)
        return self.offer(profile, request_id)

    def reject(self, error: str, request_id: str | None = None) -> SlotState:
        """A request that failed before it became a profile (bad JSON, oversized, binary)."""
        return self._reject(error, request_id)

    def _reject(self, error: str, request_id: str | None) -> SlotState:
        s = self.state
        self.state = SlotState(s.sysid, s.profile, s.hash, s.since, request_id, False, error)
        return self.state

"""The ``attack/mode`` switch: the link's attack stage on, or bypassed with its profile kept."""

from __future__ import annotations

import time
from typing import Any

from mitm_proxy.control.switch import Switch
from mitm_proxy.stages.attack import AttackStage
from secuav_common.controlplane.payloads import ModeState
from secuav_common.controlplane.switches.mode import CONTRACT, ModeRequest

__all__ = ["ModeSwitch"]


class ModeSwitch(Switch[ModeState]):
    """``attack/mode/set``: ``"on"`` or ``"bypass"`` (or ``{"mode": ...}``); the profile stays installed.

    The attack stage's ``enabled`` flag is what the pipeline reads; this switch is the one that writes it
    (``--attack bypass`` at start is :meth:`set` too).
    """

    contract = CONTRACT

    def __init__(self, sysid: int, stage: AttackStage) -> None:
        super().__init__()
        self.sysid = sysid
        self.stage = stage
        self._since = time.time()

    def set(self, on: bool, request_id: str | None = None, source: str = "<app>") -> ModeState:
        return self.handle("on" if on else "bypass", request_id, source)

    def apply(self, payload: Any, source: str) -> None:
        assert isinstance(payload, ModeRequest)  # the contract's request model, checked by handle()
        on = payload.mode == "on"
        if self.stage.enabled != on:
            self.stage.enabled = on
            self._since = time.time()

    def current(self) -> dict[str, Any]:
        return {"sysid": self.sysid, "mode": "on" if self.stage.enabled else "bypass", "since": self._since}

"""The ``secure`` switch: which estimator the link's secure stage runs (``secuav/v<N>/secure/set``)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from mitm_proxy.control.switch import RequestError, Switch
from mitm_proxy.stages.secure.config import SecureConfig, config_from_payload
from secuav_common.controlplane.payloads import SecureState
from secuav_common.controlplane.switches.secure import CONTRACT

if TYPE_CHECKING:
    from mitm_proxy.stages.secure.stage import SecureStage  # numpy/scipy: the proxy imports it only with a scenario

__all__ = ["NoSecure", "SecureSwitch"]


class SecureSwitch(Switch[SecureState]):
    """The secure stage of one link and the one door for changing it (``--secure``, config, MQTT)."""

    contract = CONTRACT

    def __init__(self, stage: SecureStage) -> None:
        super().__init__()
        self.stage = stage
        self.sysid = stage.sysid
        self._since = time.time()

    def current(self) -> dict[str, Any]:
        cfg = self.stage.config
        group = None if self.stage.layout is None else self.stage.layout.group
        return {"sysid": self.sysid, "estimator": cfg.estimator, "params": dict(cfg.params), "group": group,
                "direction": cfg.direction, "since": self._since, "warnings": self.stage.warnings}  # fmt: skip

    def apply(self, payload: Any, source: str) -> None:
        """A :class:`SecureConfig`, or the request model of ``secure/set`` (fields left out keep their value)."""
        config = payload if isinstance(payload, SecureConfig) else config_from_payload(
            payload, source, base=self.stage.config)  # fmt: skip
        self.stage.reconfigure(config, source)
        self._since = time.time()

    def offer(self, config: SecureConfig, request_id: str | None = None, source: str = "<secure>") -> SecureState:
        return self.handle(config, request_id, source)

    def offer_payload(self, payload: Any, request_id: str | None = None, source: str = "<mqtt>") -> SecureState:
        """Decoded JSON of ``secure/set``; a ``request_id`` inside it counts when none is given."""
        if request_id is None and isinstance(payload, dict) and isinstance(payload.get("request_id"), str):
            request_id = payload["request_id"]
        return self.handle(payload, request_id, source)

    def close(self) -> None:
        self.stage.close()


class NoSecure(Switch[SecureState]):
    """``secure/set`` on a link without a secure stage (no ``--scenario``): every request is refused, with why."""

    contract = CONTRACT

    def __init__(self, sysid: int) -> None:
        super().__init__()
        self.sysid = sysid

    def apply(self, payload: Any, source: str) -> None:
        raise RequestError("the secure stage is not available in this proxy (start it with --scenario)")

    def current(self) -> dict[str, Any]:
        return {"sysid": self.sysid, "available": False, "estimator": None}

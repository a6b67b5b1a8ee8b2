"""The ``routes`` switch: the endpoints' routing rules of this proxy (``secuav/proxy/[<instance>/]routes/set``)."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from mitm_proxy.control.switch import RequestError, Switch
from mitm_proxy.net.rules import NO_RULES, EndpointRules
from secuav_common.controlplane.payloads import RoutesState, error_text
from secuav_common.controlplane.switches.routes import CONTRACT, RoutesRequest

if TYPE_CHECKING:
    from mitm_proxy.control.link import SwitchHost
    from mitm_proxy.net.endpoints import BaseEndpoint

log = logging.getLogger(__name__)

__all__ = ["RoutesSwitch"]


class RoutesSwitch(Switch[RoutesState]):
    """``routes/set``: new rules for named endpoints, all checked before any is installed.

    Payload: ``{"endpoints": {"<name or URL>": <rules> | null, ...}}`` where ``<rules>`` is
    an :class:`~mitm_proxy.net.rules.EndpointRules` object (``{"listen_only": true, "down":
    {"deny": ["ATTITUDE"]}}``) and ``null`` lifts every rule. An endpoint is named as the
    stats name it (``ground:14550``) or by its URL without options; endpoints left out
    keep their rules.
    """

    contract = CONTRACT

    def __init__(self, instance: str, endpoints: Mapping[str, BaseEndpoint]) -> None:
        super().__init__()
        self.instance = instance
        self.endpoints = dict(endpoints)  # name -> BaseEndpoint
        self._since = time.time()

    @classmethod
    def build(cls, host: SwitchHost, sysid: int | None) -> RoutesSwitch | None:
        """The process's routes; none where there are no endpoints to route (a registry built for tests)."""
        return cls(host.instance, host.endpoints) if sysid is None and host.endpoints else None

    def _find(self, key: str) -> BaseEndpoint:
        ep = self.endpoints.get(key)
        if ep is not None:
            return ep
        for candidate in self.endpoints.values():
            if key in (str(candidate.endpoint), str(candidate.endpoint.without_options())):
                return candidate
        known = ", ".join(sorted(self.endpoints))
        raise RequestError(f"endpoints.{key}: no such endpoint in this proxy (known: {known})")

    def apply(self, payload: Any, source: str) -> None:
        assert isinstance(payload, RoutesRequest)  # the contract's request model, checked by handle()
        plan: list[tuple[BaseEndpoint, EndpointRules]] = []
        for key, raw in payload.endpoints.items():
            ep = self._find(key)
            try:
                rules = NO_RULES if raw is None else EndpointRules.model_validate(raw)
            except ValidationError as exc:
                raise RequestError(error_text(exc, prefix=f"endpoints.{key}.")) from None
            if rules.listen_only and ep.role != "ground":
                raise RequestError(f"endpoints.{key}.listen_only: only a ground endpoint can be listen-only")
            plan.append((ep, rules))
        for ep, rules in plan:  # everything checked: install (nothing above touched an endpoint)
            ep.set_rules(rules)
        self._since = time.time()
        log.info("routes.installed", extra={"endpoints": ",".join(ep.name for ep, _ in plan)})

    def current(self) -> dict[str, Any]:
        return {
            "instance": self.instance,
            "since": self._since,
            "endpoints": {
                name: {"url": str(ep.endpoint.without_options()), "role": ep.role,
                       "rules": ep.gate.rules.model_dump(exclude_defaults=True)}
                for name, ep in self.endpoints.items()
            },
        }  # fmt: skip

"""The proxy's side of the runtime switches, and the registry the MQTT session dispatches into.

Each switch is declared once, in ``secuav_common/controlplane/switches/<name>.py``
(its topic leaf, scope, state model, ``secuav-attack`` verbs and where its
implementation lives); the proxy side is a :class:`~mitm_proxy.control.switch.Switch`:

===============  ===============================  ==========================================  ===============
kind, scope      what it holds                    implementation                              secuav-attack
===============  ===============================  ==========================================  ===============
``attack``       the active attack profile        :class:`~mitm_proxy.stages.attack_slot.     ``apply``,
vehicle                                           AttackSlot`                                 ``clear``
``attack/mode``  the attack stage on or bypassed  :class:`ModeSwitch`                         ``mode``
vehicle
``secure``       the secure stage's estimator     :class:`~mitm_proxy.stages.secure.stage.    ``secure``
vehicle                                           SecureSlot`, :class:`NoSecure` (no
                                                  scenario)
``routes``       the endpoints' routing rules     :class:`RoutesSwitch`                       ``routes``
proxy
===============  ===============================  ==========================================  ===============

A vehicle switch is set on ``secuav/v<N>/<kind>/set``, a proxy-wide one on
``secuav/proxy/<kind>/set`` (every proxy) or ``secuav/proxy/<instance>/<kind>/set``.
Each answers on the retained ``.../<kind>/state`` next to its ``set`` topic (a
proxy-wide switch on ``secuav/proxy/<instance>/<kind>/state``) with its spec's
state model.

:func:`build_controls` fills the registry (:class:`Controls`) from the declared
switches, calling each spec's factory for every link (or once, for a proxy-wide
switch) with what the proxy holds (:class:`~mitm_proxy.control.switch.SwitchHost`);
a factory that returns ``None`` leaves that switch out there. The MQTT session
(:mod:`mitm_proxy.control.plane`) dispatches into the registry; it is sans-I/O,
so tests drive it directly.
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from mitm_proxy.control.switch import Switch, SwitchHost
from mitm_proxy.net.rules import NO_RULES, EndpointRules
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.controlplane import switches as declared
from secuav_common.controlplane.payloads import ModeState, RequestError, RoutesState, SecureState
from secuav_common.controlplane.switches import mode as mode_spec
from secuav_common.controlplane.switches import routes as routes_spec
from secuav_common.controlplane.switches import secure as secure_spec
from secuav_common.controlplane.topics import (
    ANY,
    INSTANCE_RE,
    PREFIX,
    parse,
    parse_vehicle_key,
    proxy_topic,
    vehicle_topic,
)

if TYPE_CHECKING:
    from mitm_proxy.net.endpoints import BaseEndpoint
    from mitm_proxy.stages.secure.stage import SecureSlot  # numpy/scipy: imported by the proxy only with a scenario

log = logging.getLogger(__name__)

__all__ = ["INSTANCE_RE", "PREFIX", "RequestError", "parse_vehicle_key", "proxy_topic", "vehicle_topic"]


def default_instance() -> str:
    """``<host>-<pid>``, cleaned to what a topic level may hold: unique per process on one broker."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname())[:40] or "host"
    return f"{host}-{os.getpid()}"


MODES = {"on": True, "bypass": False}


class ModeSwitch(Switch[ModeState]):
    """``attack/mode/set``: ``"on"`` or ``"bypass"`` (or ``{"mode": ...}``); the profile stays installed.

    The attack stage's ``enabled`` flag is what the pipeline reads; this switch is the one that writes it
    (``--attack bypass`` at start is :meth:`set` too).
    """

    spec = mode_spec.SPEC

    def __init__(self, sysid: int, stage: AttackStage, on: bool | None = None) -> None:
        super().__init__()
        self.sysid = sysid
        self.stage = stage
        if on is not None:
            stage.enabled = on
        self._since = time.time()

    @classmethod
    def build(cls, host: SwitchHost, sysid: int | None) -> ModeSwitch | None:
        """The link's mode switch (the proxy makes it with the stage, for ``--attack``), else one for its
        attack stage; none where the link has no stage."""
        if sysid is None:
            return None
        parts = host.links[sysid]
        if parts.mode is not None:
            return parts.mode
        return None if parts.stage is None else cls(sysid, parts.stage)

    def set(self, on: bool, request_id: str | None = None, source: str = "<app>") -> ModeState:
        return self.handle("on" if on else "bypass", request_id, source)

    def apply(self, payload: Any, source: str) -> None:
        value = payload.get("mode") if isinstance(payload, dict) else payload
        if not (isinstance(value, str) and value in MODES):
            raise RequestError(f'mode: must be "on" or "bypass" (got {json.dumps(value)[:40]})')
        if self.stage.enabled != MODES[value]:
            self.stage.enabled = MODES[value]
            self._since = time.time()

    def current(self) -> dict[str, Any]:
        return {"sysid": self.sysid, "mode": "on" if self.stage.enabled else "bypass", "since": self._since}


class NoSecure(Switch[SecureState]):
    """``secure/set`` on a link without a secure stage (no ``--scenario``): every request is refused, with why."""

    spec = secure_spec.SPEC

    def __init__(self, sysid: int) -> None:
        super().__init__()
        self.sysid = sysid

    def apply(self, payload: Any, source: str) -> None:
        raise RequestError("the secure stage is not available in this proxy (start it with --scenario)")

    def current(self) -> dict[str, Any]:
        return {"sysid": self.sysid, "available": False, "estimator": None}


def secure_switch(host: SwitchHost, sysid: int | None) -> Switch[SecureState] | None:
    """The link's secure slot (made with the link when there is a scenario), else :class:`NoSecure`."""
    if sysid is None:
        return None
    slot = host.links[sysid].secure
    return slot if slot is not None else NoSecure(sysid)


class RoutesSwitch(Switch[RoutesState]):
    """``routes/set``: new rules for named endpoints, all checked before any is installed.

    Payload: ``{"endpoints": {"<name or URL>": <rules> | null, ...}}`` where ``<rules>`` is
    an :class:`~mitm_proxy.net.rules.EndpointRules` object (``{"listen_only": true, "down":
    {"deny": ["ATTITUDE"]}}``) and ``null`` lifts every rule. An endpoint is named as the
    stats name it (``ground:14550``) or by its URL without options; endpoints left out
    keep their rules.
    """

    spec = routes_spec.SPEC

    def __init__(self, instance: str, endpoints: Mapping[str, BaseEndpoint]) -> None:
        super().__init__()
        self.instance = instance
        self.endpoints = dict(endpoints)  # name -> BaseEndpoint
        self._since = time.time()

    @classmethod
    def build(cls, host: SwitchHost, sysid: int | None) -> RoutesSwitch | None:
        """The process's routes; none where there are no endpoints to route (a registry built for tests)."""
        return cls(host.instance, host.endpoints) if host.endpoints else None

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
        body = payload.get("endpoints") if isinstance(payload, dict) else None
        if not isinstance(body, dict) or not body:
            raise RequestError('endpoints: expected {"endpoints": {"<name>": {rules} or null, ...}}')
        extra = sorted(set(payload) - {"endpoints", "request_id"})
        if extra:
            raise RequestError(f"{extra[0]}: unknown field (known: endpoints, request_id)")
        plan: list[tuple[BaseEndpoint, EndpointRules]] = []
        for key, raw in body.items():
            ep = self._find(str(key))
            try:
                rules = NO_RULES if raw is None else EndpointRules.model_validate(raw)
            except ValidationError as exc:
                err = exc.errors()[0]
                where = ".".join(str(p) for p in err["loc"])
                value = json.dumps(err.get("input"), default=str)[:60]
                raise RequestError(f"endpoints.{key}.{where}: {err['msg']} (got {value})") from None
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


@dataclass(frozen=True, slots=True)
class Target:
    """Where a ``set`` topic leads: the control, its state topic, and the scope for the log."""

    control: Switch[Any]
    state_topic: str


class Controls:
    """The registry: every control of one proxy process, by topic."""

    def __init__(self, instance: str) -> None:
        if not INSTANCE_RE.match(instance):
            raise ValueError(f"instance name {instance!r}: use 1-64 letters, digits, '.', '_' or '-'")
        self.instance = instance
        self._vehicles: dict[int, dict[str, Switch[Any]]] = {}
        self._proxy: dict[str, Switch[Any]] = {}

    def add(self, switch: Switch[Any], sysid: int | None = None) -> Switch[Any]:
        """Register ``switch``: a vehicle's (``sysid``) or, for a proxy-wide one, the process's."""
        if switch.scope == "proxy":
            self._proxy[switch.kind] = switch
        else:
            assert sysid is not None, f"a {switch.kind} switch belongs to a vehicle"
            self._vehicles.setdefault(sysid, {})[switch.kind] = switch
        return switch

    def add_vehicle(self, sysid: int, switch: Switch[Any]) -> Switch[Any]:
        return self.add(switch, sysid)

    def add_proxy(self, switch: Switch[Any]) -> Switch[Any]:
        return self.add(switch)

    @property
    def vehicles(self) -> list[int]:
        return sorted(self._vehicles)

    def vehicle(self, sysid: int, kind: str) -> Switch[Any] | None:
        return self._vehicles.get(sysid, {}).get(kind)

    def subscriptions(self) -> list[str]:
        kinds = sorted({k for controls in self._vehicles.values() for k in controls})
        topics = [vehicle_topic(ANY, k, "set") for k in kinds]
        for kind in sorted(self._proxy):
            topics += [proxy_topic(None, kind, "set"), proxy_topic(self.instance, kind, "set")]
        return topics

    def states(self) -> Iterator[Target]:
        """Every control with the topic its state goes to, vehicles first."""
        for sysid, controls in sorted(self._vehicles.items()):
            for kind, control in controls.items():
                yield Target(control, vehicle_topic(sysid, kind, "state"))
        for kind, control in self._proxy.items():
            yield Target(control, proxy_topic(self.instance, kind, "state"))

    def route(self, topic: str) -> Target | str | None:
        """The control a ``.../set`` topic addresses; a vehicle key we do not serve comes back as
        that key (for the log), anything else that is not ours as ``None``."""
        parsed = parse(topic)
        if parsed is None or parsed.verb != "set" or parsed.scope == "console":
            return None
        if parsed.scope == "proxy":
            if parsed.key is not None and parsed.key != self.instance:
                return None  # another proxy's
            control = self._proxy.get(parsed.leaf)
            return None if control is None else Target(control, proxy_topic(self.instance, parsed.leaf, "state"))
        sysid = parsed.sysid
        controls = self._vehicles.get(sysid) if sysid is not None else None
        if controls is None:
            return parsed.key if any(parsed.leaf in c for c in self._vehicles.values()) else None
        control = controls.get(parsed.leaf)
        return None if control is None else Target(control, parsed.with_verb("state"))


def build_controls(host: SwitchHost) -> Controls:
    """The registry of every declared switch: each spec's factory, for every link (in sysid order) or, for a
    proxy-wide switch, once."""
    controls = Controls(host.instance)
    for spec in declared.specs():
        factory = spec.load()
        if spec.scope == "proxy":
            switch = factory(host, None)
            if switch is not None:
                controls.add(switch)
            continue
        for sysid in sorted(host.links):
            switch = factory(host, sysid)
            if switch is not None:
                controls.add(switch, sysid)
    return controls


@dataclass(slots=True)
class _Link:
    sysid: int
    slot: AttackSlot
    stage: AttackStage | None = None
    mode: ModeSwitch | None = None
    secure: SecureSlot | None = None


def vehicle_controls(
    instance: str,
    slots: Mapping[int, AttackSlot],
    modes: Mapping[int, ModeSwitch | AttackStage] | None = None,
    secure: Mapping[int, SecureSlot] | None = None,
) -> Controls:
    """The registry for a set of links without endpoints (tests, tools): :func:`build_controls` over the
    attack slots, the mode switches or attack stages where given, and the secure slots (:class:`NoSecure`,
    refusing every request with the reason, on a link without one)."""
    links: dict[int, _Link] = {}
    for sysid, slot in slots.items():
        mode = None if modes is None else modes.get(sysid)
        links[sysid] = _Link(
            sysid, slot,
            stage=mode.stage if isinstance(mode, ModeSwitch) else mode,
            mode=mode if isinstance(mode, ModeSwitch) else None,
            secure=None if secure is None else secure.get(sysid),
        )  # fmt: skip
    return build_controls(SwitchHost(instance, links))

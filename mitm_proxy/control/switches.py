"""The proxy's runtime switches, one class per kind, and the registry the MQTT session dispatches into.

Each switch is declared on the wire once, in ``secuav_common/controlplane/switches/<kind>.py``
(its contract: topic leaf, scope, state and request models); the proxy's side is one
:class:`~mitm_proxy.control.switch.Switch` class per kind, in its own module here, wrapping its stage:

===============  ===============================  =====================================  ===============
kind, scope      what it holds                    proxy side                             secuav-attack
===============  ===============================  =====================================  ===============
``attack``       the active attack profile        :class:`~mitm_proxy.control.attack.     ``apply``,
vehicle                                           AttackSwitch` (the stage's slot)       ``clear``
``attack/mode``  the attack stage on or bypassed  :class:`~mitm_proxy.control.mode.       ``mode``
vehicle                                           ModeSwitch` (the attack stage)
``secure``       the secure stage's estimator     :class:`~mitm_proxy.control.secure.     ``secure``
vehicle                                           SecureSwitch`, ``NoSecure`` (no
                                                  scenario)
``routes``       the endpoints' routing rules     :class:`~mitm_proxy.control.routes.     ``routes``
proxy                                             RoutesSwitch` (the endpoints)
===============  ===============================  =====================================  ===============

A vehicle switch is set on ``secuav/v<N>/<kind>/set``, a proxy-wide one on
``secuav/proxy/<kind>/set`` (every proxy) or ``secuav/proxy/<instance>/<kind>/set``.
Each answers on the retained ``.../<kind>/state`` next to its ``set`` topic (a
proxy-wide switch on ``secuav/proxy/<instance>/<kind>/state``) with its contract's
state model.

:data:`BUILT_IN` lists the classes; :func:`register` adds one more by an explicit call.
:func:`build_controls` fills the registry (:class:`Controls`): each link's own
switches (:meth:`~mitm_proxy.control.link.LinkParts.switches`), then each class no
link holds, built from what the proxy holds (:class:`~mitm_proxy.control.link.SwitchHost`). The MQTT session
(:mod:`mitm_proxy.control.plane`) dispatches into the registry; it is sans-I/O,
so tests drive it directly.
"""

from __future__ import annotations

import logging
import os
import re
import socket
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.link import LinkParts, SwitchHost
from mitm_proxy.control.mode import ModeSwitch
from mitm_proxy.control.routes import RoutesSwitch
from mitm_proxy.control.secure import SecureSwitch
from mitm_proxy.control.switch import RequestError, Switch
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from secuav_common.controlplane.topics import (
    ANY,
    INSTANCE_RE,
    PREFIX,
    Scope,
    parse,
    parse_vehicle_key,
    proxy_topic,
    vehicle_topic,
)
from secuav_common.registry import Registry

log = logging.getLogger(__name__)

__all__ = ["INSTANCE_RE", "PREFIX", "RequestError", "parse_vehicle_key", "proxy_topic", "vehicle_topic"]


def default_instance() -> str:
    """``<host>-<pid>``, cleaned to what a topic level may hold: unique per process on one broker."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname())[:40] or "host"
    return f"{host}-{os.getpid()}"


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


class Built(Protocol):
    """A switch class no link holds: it builds its switch from what the process holds (None leaves it out).
    ``sysid`` is a link's for a vehicle switch, None for a proxy-wide one."""

    kind: str
    scope: Scope

    def build(self, host: SwitchHost, sysid: int | None) -> Switch[Any] | None: ...


# Every built-in kind, one class each: the first three are held by each link (LinkParts.switches; NoSecure
# stands in for SecureSwitch on a link without a scenario), routes is built from the endpoints.
BUILT_IN: tuple[type[Switch[Any]], ...] = (AttackSwitch, ModeSwitch, SecureSwitch, RoutesSwitch)
_HELD_BY_LINKS = frozenset({AttackSwitch, ModeSwitch, SecureSwitch})
TABLE: Registry[type[Switch[Any]]] = Registry("switch")
for _cls in BUILT_IN:
    TABLE.register(_cls.kind, _cls)


def register(switch: Built) -> Built:
    """Serve one more switch class (its contract registered in secuav_common too); a kind twice is a bug."""
    TABLE.add(switch.kind, switch)  # type: ignore[arg-type]  # a Built is a Switch class with build()
    return switch


def unregister(kind: str) -> None:
    """Take an added switch class out again (tests that declare one of their own)."""
    TABLE.remove(kind)


def build_controls(host: SwitchHost) -> Controls:
    """The registry of every switch: each link's own (in sysid order), then each class no link holds, built
    for every link or, for a proxy-wide switch, once."""
    controls = Controls(host.instance)
    for sysid, link in sorted(host.links.items()):
        for switch in link.switches():
            controls.add(switch, sysid)
    for cls in [c for c in TABLE.table.values() if c not in _HELD_BY_LINKS]:
        for sysid in [None] if cls.scope == "proxy" else sorted(host.links):
            built = cls.build(host, sysid)
            if built is not None:
                controls.add(built, sysid)
    return controls


def vehicle_controls(
    instance: str,
    attack: Mapping[int, AttackSwitch],
    modes: Mapping[int, ModeSwitch | AttackStage] | None = None,
    secure: Mapping[int, SecureSwitch] | None = None,
) -> Controls:
    """The registry for a set of links without endpoints (tests, tools): :func:`build_controls` over the
    attack switches, the mode switches (or the attack stages they switch; a stage of its own where none
    is given), and the secure switches (:class:`~mitm_proxy.control.secure.NoSecure`, refusing every
    request with the reason, on a link without one)."""
    links: dict[int, LinkParts] = {}
    for sysid, switch in attack.items():
        given = None if modes is None else modes.get(sysid)
        mode = given if isinstance(given, ModeSwitch) else None
        stage = mode.stage if mode is not None else given if given is not None else AttackStage(switch.slot)
        links[sysid] = LinkParts(sysid, stage, switch, mode or ModeSwitch(sysid, stage), LinkStats(sysid),
                                 None if secure is None else secure.get(sysid))  # fmt: skip
    return build_controls(SwitchHost(instance, links))

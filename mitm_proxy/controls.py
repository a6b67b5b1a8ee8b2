"""Runtime switches, one shape for all: validate a request, apply it atomically, report the state.

Everything the control plane can change at runtime is a :class:`Control`:

=============  ==========================================  ==============================
kind           set on                                      what it holds
=============  ==========================================  ==============================
``attack``     ``secuav/v<N>/attack/set``                  the active attack profile
``attack/mode``  ``secuav/v<N>/attack/mode/set``           the attack stage on or bypassed
``secure``     ``secuav/v<N>/secure/set``                  the secure stage's estimator
``routes``     ``secuav/proxy/routes/set`` (every proxy),  the endpoints' routing rules
               ``secuav/proxy/<instance>/routes/set``
=============  ==========================================  ==============================

Each answers on the retained ``.../<kind>/state`` next to its ``set`` topic (a
proxy-wide control on ``secuav/proxy/<instance>/<kind>/state``). A control
never half-applies: it builds and checks everything first, then installs it
with one assignment, and the event loop runs one callback at a time, so a
change always falls between two frames. A refused request leaves the old
setting in place and says why in the state.

:class:`Controls` is the registry the proxy fills once and the MQTT session
(:mod:`mitm_proxy.control`) dispatches into; it is sans-I/O, so tests drive
it directly.
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import ValidationError

from mitm_proxy.routes import NO_RULES, EndpointRules
from mitm_proxy.slots import AttackSlot
from secuav_common.controlplane.payloads import RequestError
from secuav_common.controlplane.topics import (
    ANY,
    INSTANCE_RE,
    PREFIX,
    parse,
    parse_vehicle_key,
    proxy_topic,
    vehicle_topic,
)
from secuav_common.loading import InputError

log = logging.getLogger("mitm_proxy.control")

__all__ = ["INSTANCE_RE", "PREFIX", "RequestError", "parse_vehicle_key", "proxy_topic", "vehicle_topic"]


def default_instance() -> str:
    """``<host>-<pid>``, cleaned to what a topic level may hold: unique per process on one broker."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname())[:40] or "host"
    return f"{host}-{os.getpid()}"


class Control(ABC):
    """One runtime switch. ``apply`` raises :class:`RequestError` (or ``InputError``) to refuse."""

    kind: ClassVar[str]
    bare_words: ClassVar[frozenset[bytes]] = frozenset()  # accepted without JSON quotes (``mosquitto_pub -m off``)

    def __init__(self) -> None:
        self._request_id: str | None = None
        self._error: str | None = None

    @abstractmethod
    def apply(self, payload: Any, request_id: str | None) -> None:
        """Validate ``payload`` completely, then install it in one step."""

    @abstractmethod
    def current(self) -> dict[str, Any]:
        """What is in force now (without the verdict on the last request)."""

    def state(self) -> dict[str, Any]:
        """The retained ``.../state``: what is in force and the verdict on the last request."""
        return {**self.current(), "request_id": self._request_id, "ok": self._error is None, "error": self._error}

    def handle(self, payload: Any, request_id: str | None) -> dict[str, Any]:
        """Apply a decoded request and return the state to publish; never raises."""
        try:
            self.apply(payload, request_id)
        except (RequestError, InputError) as exc:
            return self.refuse(str(exc), request_id)
        except Exception as exc:  # a library bug must not end the control plane; the old setting stays
            log.exception(f"{self.kind.replace('/', '_')}.failed", extra={"request_id": request_id})
            return self.refuse(f"internal error: {exc!r}", request_id)
        self._request_id, self._error = request_id, None
        return self.state()

    def refuse(self, error: str, request_id: str | None) -> dict[str, Any]:
        self._request_id, self._error = request_id, error
        log.warning(f"{self.kind.replace('/', '_')}.rejected", extra={"error": error, "request_id": request_id})
        return self.state()


class AttackControl(Control):
    """``attack/set``: a profile, ``{"library": name, "params": {...}}`` or ``null``, into the link's slot.

    The slot keeps its own state (the file reload and ``--profile`` change it too), so this control
    hands the verdict to the slot rather than keeping one.
    """

    kind = "attack"

    def __init__(self, slot: AttackSlot) -> None:
        super().__init__()
        self.slot = slot

    def apply(self, payload: Any, request_id: str | None) -> None:
        state = self.slot.offer_payload(payload, request_id, source=vehicle_topic(self.slot.sysid, "attack", "set"))
        if not state.ok:
            raise RequestError(state.error or "rejected")
        log.info("attack.applied", extra={"sysid": self.slot.sysid, "profile": state.profile,
                                          "request_id": request_id})  # fmt: skip

    def current(self) -> dict[str, Any]:
        return self.slot.state.to_json()

    def state(self) -> dict[str, Any]:
        return self.slot.state.to_json()

    def refuse(self, error: str, request_id: str | None) -> dict[str, Any]:
        if self.slot.state.request_id != request_id or self.slot.state.error != error:
            self.slot.reject(error, request_id)
        log.warning("attack.rejected", extra={"sysid": self.slot.sysid, "error": error, "request_id": request_id})
        return self.state()


MODES = {"on": True, "bypass": False}


class ModeControl(Control):
    """``attack/mode/set``: ``"on"`` or ``"bypass"`` (or ``{"mode": ...}``); the profile stays installed."""

    kind = "attack/mode"
    bare_words = frozenset(m.encode() for m in MODES)

    def __init__(self, sysid: int, stage: Any) -> None:
        super().__init__()
        self.sysid = sysid
        self.stage = stage  # anything with a bool ``enabled`` (the link's AttackStage)
        self._mode = self._now()
        self._since = time.time()

    def _now(self) -> str:
        return "on" if self.stage.enabled else "bypass"

    def apply(self, payload: Any, request_id: str | None) -> None:
        value = payload.get("mode") if isinstance(payload, dict) else payload
        if not (isinstance(value, str) and value in MODES):
            raise RequestError(f'mode: must be "on" or "bypass" (got {json.dumps(value)[:40]})')
        self.stage.enabled = MODES[value]
        if value != self._mode:
            self._mode, self._since = value, time.time()
        log.info("attack.mode", extra={"sysid": self.sysid, "mode": value, "request_id": request_id})

    def current(self) -> dict[str, Any]:
        mode = self._now()
        if mode != self._mode:  # switched by someone else (the app): no request of ours did it
            self._mode, self._since = mode, time.time()
            self._request_id, self._error = None, None
        return {"sysid": self.sysid, "mode": mode, "since": self._since}


class SecureControl(Control):
    """``secure/set``: an estimator name, ``{"estimator": ..., "params": {...}}``, or ``"off"``/``null``.

    ``slot`` is the link's :class:`~mitm_proxy.secure.SecureSlot`, which keeps its own verdict
    (``secure/state`` predates this module); without one (no ``--scenario``) every request is refused.
    """

    kind = "secure"
    bare_words = frozenset({b"off"})

    def __init__(self, sysid: int, slot: Any | None) -> None:
        super().__init__()
        self.sysid = sysid
        self.slot = slot

    def apply(self, payload: Any, request_id: str | None) -> None:
        if self.slot is None:
            raise RequestError("the secure stage is not available in this proxy (start it with --scenario)")
        state = self.slot.offer_payload(payload, request_id)
        if not state.get("ok"):
            raise RequestError(str(state.get("error")))
        log.info("secure.applied", extra={"sysid": self.sysid, "estimator": state.get("estimator"),
                                          "request_id": request_id})  # fmt: skip

    def current(self) -> dict[str, Any]:
        if self.slot is None:
            return {"sysid": self.sysid, "available": False, "estimator": None}
        return dict(self.slot.state)

    def state(self) -> dict[str, Any]:
        if self.slot is not None:
            return dict(self.slot.state)
        return super().state()

    def refuse(self, error: str, request_id: str | None) -> dict[str, Any]:
        if self.slot is not None:
            state = self.slot.state
            if state.get("request_id") != request_id or state.get("error") != error:
                self.slot.reject(error, request_id)
            log.warning("secure.rejected", extra={"sysid": self.sysid, "error": error, "request_id": request_id})
            return self.state()
        return super().refuse(error, request_id)


class RoutesControl(Control):
    """``routes/set``: new rules for named endpoints, all checked before any is installed.

    Payload: ``{"endpoints": {"<name or URL>": <rules> | null, ...}}`` where ``<rules>`` is
    an :class:`~mitm_proxy.routes.EndpointRules` object (``{"listen_only": true, "down":
    {"deny": ["ATTITUDE"]}}``) and ``null`` lifts every rule. An endpoint is named as the
    stats name it (``ground:14550``) or by its URL without options; endpoints left out
    keep their rules.
    """

    kind = "routes"

    def __init__(self, instance: str, endpoints: Mapping[str, Any]) -> None:
        super().__init__()
        self.instance = instance
        self.endpoints = dict(endpoints)  # name -> BaseEndpoint
        self._since = time.time()

    def _find(self, key: str) -> Any:
        ep = self.endpoints.get(key)
        if ep is not None:
            return ep
        for candidate in self.endpoints.values():
            if key in (str(candidate.endpoint), str(candidate.endpoint.without_options())):
                return candidate
        known = ", ".join(sorted(self.endpoints))
        raise RequestError(f"endpoints.{key}: no such endpoint in this proxy (known: {known})")

    def apply(self, payload: Any, request_id: str | None) -> None:
        body = payload.get("endpoints") if isinstance(payload, dict) else None
        if not isinstance(body, dict) or not body:
            raise RequestError('endpoints: expected {"endpoints": {"<name>": {rules} or null, ...}}')
        extra = sorted(set(payload) - {"endpoints", "request_id"})
        if extra:
            raise RequestError(f"{extra[0]}: unknown field (known: endpoints, request_id)")
        plan: list[tuple[Any, EndpointRules]] = []
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
        log.info("routes.applied", extra={"endpoints": ",".join(ep.name for ep, _ in plan), "request_id": request_id})

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

    control: Control
    state_topic: str


class Controls:
    """The registry: every control of one proxy process, by topic."""

    def __init__(self, instance: str) -> None:
        if not INSTANCE_RE.match(instance):
            raise ValueError(f"instance name {instance!r}: use 1-64 letters, digits, '.', '_' or '-'")
        self.instance = instance
        self._vehicles: dict[int, dict[str, Control]] = {}
        self._proxy: dict[str, Control] = {}

    def add_vehicle(self, sysid: int, control: Control) -> Control:
        self._vehicles.setdefault(sysid, {})[control.kind] = control
        return control

    def add_proxy(self, control: Control) -> Control:
        self._proxy[control.kind] = control
        return control

    @property
    def vehicles(self) -> list[int]:
        return sorted(self._vehicles)

    def vehicle(self, sysid: int, kind: str) -> Control | None:
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


def vehicle_controls(
    instance: str,
    slots: Mapping[int, AttackSlot],
    stages: Mapping[int, Any] | None = None,
    secure: Mapping[int, Any] | None = None,
) -> Controls:
    """The registry for a set of links: attack on every slot, mode where there is a stage, and secure
    (refusing every request, with the reason, on a link without a secure slot)."""
    controls = Controls(instance)
    for sysid, slot in slots.items():
        controls.add_vehicle(sysid, AttackControl(slot))
        if stages is not None and sysid in stages:
            controls.add_vehicle(sysid, ModeControl(sysid, stages[sysid]))
        controls.add_vehicle(sysid, SecureControl(sysid, None if secure is None else secure.get(sysid)))
    return controls

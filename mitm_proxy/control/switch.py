"""The one shape of every runtime switch: validate a request, apply it atomically, keep one typed verdict.

A :class:`Switch` is the proxy's side of a switch declared in
``secuav_common/controlplane/switches/<name>.py`` (its :class:`SwitchSpec`: topic
leaf, scope, state and request models, ``secuav-attack`` verbs). It owns what it
switches (the attack profile, the attack stage's mode, the secure stage's
estimator, the endpoints' rules) and the verdict on the last request; its class
names its spec (``spec = SPEC``), from which ``kind`` (``secuav/v<N>/<kind>/set``
and ``.../state``), ``scope``, ``state_model`` and ``bare_words`` follow, and the
spec's ``implementation`` names the factory the proxy's registry calls to build
or find it for each link (``build(host, sysid)``). Every change, whichever door it came through (MQTT, the
``--profile`` file reload, a flag at start, ``secuav-record``), goes through
:meth:`Switch.handle`, so the verdict is kept in one place and the published
state always says what is in force.

A switch never half-applies: :meth:`Switch.apply` builds and checks
everything first, then installs it with one assignment, and the event loop
runs one callback at a time, so a change always falls between two frames.
What is costly and pure (validating a profile) a switch may do in
:meth:`Switch.prepare`, which the MQTT session runs in a worker thread. A
refused request leaves the old setting in place and says why in the state.
"""

from __future__ import annotations

import json
import logging
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, TypeVar

from pydantic import BaseModel, ValidationError

from secuav_common.controlplane.payloads import RequestError, Verdict
from secuav_common.controlplane.switches import SwitchSpec
from secuav_common.controlplane.topics import Scope
from secuav_common.loading import InputError

if TYPE_CHECKING:
    from mitm_proxy.control.switches import ModeSwitch
    from mitm_proxy.net.endpoints import BaseEndpoint
    from mitm_proxy.stages.attack import AttackStage
    from mitm_proxy.stages.attack_slot import AttackSlot
    from mitm_proxy.stages.secure.stage import SecureSlot

log = logging.getLogger(__name__)

StateT = TypeVar("StateT", bound=BaseModel)

__all__ = ["LinkParts", "RequestError", "StateT", "Switch", "SwitchHost", "Verdict"]


class Switch(ABC, Generic[StateT]):
    """One runtime switch; subclasses say what they hold (:meth:`current`) and how a request changes it."""

    spec: ClassVar[SwitchSpec]  # the declaration this class implements; what follows is read from it
    kind: ClassVar[str]  # the topic leaf: attack, attack/mode, secure, routes
    scope: ClassVar[Scope] = "vehicle"  # or "proxy": one per process, on secuav/proxy/<instance>/<kind>/...
    state_model: ClassVar[type[BaseModel]]  # what .../state carries
    bare_words: ClassVar[frozenset[bytes]] = frozenset()  # accepted without JSON quotes (``mosquitto_pub -m off``)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        spec = cls.__dict__.get("spec")
        if spec is not None:
            cls.kind, cls.scope, cls.state_model, cls.bare_words = (
                spec.kind, spec.scope, spec.state_model, spec.bare_words)  # fmt: skip

    def __init__(self) -> None:
        self.verdict = Verdict()

    def prepare(self, payload: Any, source: str) -> Any:
        """The costly, pure part of checking a request (parsing a profile), run off the event loop by the
        MQTT session; what it returns is what :meth:`apply` gets. Raises ``RequestError``/``InputError``.

        Where the spec has a ``request_model`` the payload is checked against it here and :meth:`apply`
        gets the model; the error names the field and the value."""
        return self._checked(payload)

    def _checked(self, payload: Any) -> Any:
        spec: SwitchSpec | None = getattr(self, "spec", None)
        model = None if spec is None else spec.request_model
        if model is None or isinstance(payload, model):
            return payload
        try:
            return model.model_validate(payload)
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"]) or "(payload)"
            value = json.dumps(err.get("input"), default=str)[:60]
            raise RequestError(f"{where}: {err['msg']} (got {value})") from None

    @abstractmethod
    def apply(self, payload: Any, source: str) -> None:
        """Validate ``payload`` completely, then install it in one step; ``RequestError``/``InputError`` refuse."""

    @abstractmethod
    def current(self) -> dict[str, Any]:
        """What is in force now, as the state's fields (without the verdict)."""

    @property
    def state(self) -> StateT:
        """The retained ``.../state``: what is in force and the verdict on the last request."""
        return self.state_model(**self.current(), **self.verdict.model_dump())  # type: ignore[return-value]

    def handle(self, payload: Any, request_id: str | None, source: str = "<mqtt>") -> StateT:
        """Apply a decoded request and return the state to publish; never raises."""
        try:
            self.apply(self._checked(payload), source)
        except (RequestError, InputError) as exc:
            return self.refuse(str(exc), request_id)
        except Exception as exc:  # a library bug must not end the control plane; the old setting stays
            log.exception(f"{self.kind.replace('/', '_')}.failed", extra={"request_id": request_id})
            return self.refuse(f"internal error: {exc!r}", request_id)
        self.verdict = Verdict(request_id=request_id)
        log.info(f"{self.kind.replace('/', '_')}.applied", extra={**self._log_fields(), "request_id": request_id})
        return self.state

    def refuse(self, error: str, request_id: str | None) -> StateT:
        """A request refused before or while it was applied (bad JSON, oversized, invalid): the setting stays."""
        self.verdict = Verdict(request_id=request_id, ok=False, error=error)
        log.warning(f"{self.kind.replace('/', '_')}.rejected",
                    extra={**self._log_fields(), "error": error, "request_id": request_id})  # fmt: skip
        return self.state

    def _log_fields(self) -> dict[str, Any]:
        sysid = getattr(self, "sysid", None)
        return {} if sysid is None else {"sysid": sysid}


class LinkParts(Protocol):
    """What the proxy holds for one link, as a vehicle switch's factory finds it."""

    @property
    def sysid(self) -> int: ...
    @property
    def slot(self) -> AttackSlot: ...
    @property
    def stage(self) -> AttackStage | None: ...
    @property
    def mode(self) -> ModeSwitch | None: ...
    @property
    def secure(self) -> SecureSlot | None: ...


@dataclass(frozen=True, slots=True)
class SwitchHost:
    """What a switch's factory (its spec's ``implementation``) may build on: this process's instance name,
    its links' parts by sysid, its endpoints by name."""

    instance: str
    links: Mapping[int, LinkParts]
    endpoints: Mapping[str, BaseEndpoint] = field(default_factory=dict)

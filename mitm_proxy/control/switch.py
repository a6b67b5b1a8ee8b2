"""The one shape of every runtime switch: check a request, apply it atomically, keep one typed verdict.

A :class:`Switch` is the proxy's side of one switch: its class names the wire
contract (``contract = CONTRACT``, from ``secuav_common/controlplane/switches/<kind>.py``),
from which ``kind`` (``secuav/v<N>/<kind>/set`` and ``.../state``), ``scope``,
``state_model`` and ``bare_words`` follow, and it wraps the stage (or the
endpoints) it switches; a link holds its own switches
(:class:`~mitm_proxy.control.link.LinkParts`), and a switch no link holds is
built by its class from what the process holds (``build(host, sysid)``,
:mod:`mitm_proxy.control.switches`). Every change, whichever door it
came through (MQTT, the ``--profile`` file reload, a flag at start,
``secuav-record``), goes through :meth:`Switch.handle`, so the verdict is kept in
one place and the published state always says what is in force.

A request from the wire meets its contract's request model first, and nothing
else checks its shape; the switch gets the model. A switch never half-applies:
:meth:`Switch.apply` builds and checks everything first, then installs it with
one assignment, and the event loop runs one callback at a time, so a change
always falls between two frames. What is costly and pure (validating a profile)
a switch may do in :meth:`Switch.prepare`, which the MQTT session runs in a
worker thread. A refused request leaves the old setting in place and says why
in the state.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from typing import Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel, ValidationError

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.payloads import RequestError, Verdict, error_text
from secuav_common.controlplane.topics import Scope
from secuav_common.loading import InputError

log = logging.getLogger(__name__)

StateT = TypeVar("StateT", bound=BaseModel)

__all__ = ["RequestError", "StateT", "Switch", "Verdict"]

# What a request decoded from JSON can be; anything else was made by the proxy itself (a parsed profile at
# start, a built engine, a configuration) and has no wire shape to check.
_WIRE = (dict, list, str, int, float, bool, type(None))


class Switch(ABC, Generic[StateT]):
    """One runtime switch; subclasses say what they hold (:meth:`current`) and how a request changes it."""

    contract: ClassVar[SwitchContract]  # the wire contract this class serves; what follows is read from it
    kind: ClassVar[str]  # the topic leaf: attack, attack/mode, secure, routes
    scope: ClassVar[Scope] = "vehicle"  # or "proxy": one per process, on secuav/proxy/<instance>/<kind>/...
    state_model: ClassVar[type[BaseModel]]  # what .../state carries
    bare_words: ClassVar[frozenset[bytes]] = frozenset()  # accepted without JSON quotes (``mosquitto_pub -m off``)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        contract = cls.__dict__.get("contract")
        if contract is not None:
            cls.kind, cls.scope, cls.state_model, cls.bare_words = (
                contract.kind, contract.scope, contract.state_model, contract.bare_words)  # fmt: skip

    def __init__(self) -> None:
        self.verdict = Verdict()

    def prepare(self, payload: Any, source: str) -> Any:
        """The costly, pure part of checking a request (parsing a profile), run off the event loop by the
        MQTT session; what it returns is what :meth:`apply` gets. Raises ``RequestError``/``InputError``.

        A request from the wire is checked against the contract's request model here, and :meth:`apply`
        gets the model; the error names the field and the value."""
        return self._checked(payload)

    def _checked(self, payload: Any) -> Any:
        if not isinstance(payload, _WIRE):
            return payload
        model = self.contract.request_model
        try:
            return self.contract.check(payload)
        except ValidationError as exc:
            raise RequestError(error_text(exc, model=model)) from None

    @abstractmethod
    def apply(self, payload: Any, source: str) -> None:
        """Install what ``payload`` asks for in one step; ``RequestError``/``InputError`` refuse it."""

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

    def reject(self, error: str, request_id: str | None = None) -> StateT:
        """A request that failed before it became one (bad JSON, oversized, binary): the setting stays."""
        return self.refuse(error, request_id)

    def _log_fields(self) -> dict[str, Any]:
        sysid = getattr(self, "sysid", None)
        return {} if sysid is None else {"sysid": sysid}

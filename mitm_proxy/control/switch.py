"""The one shape of every runtime switch: validate a request, apply it atomically, keep one typed verdict.

A :class:`Switch` owns what it switches (the attack profile, the attack
stage's mode, the secure stage's estimator, the endpoints' rules), its topic
leaf (``kind``: ``secuav/v<N>/<kind>/set`` and ``.../state``) and the verdict on
the last request. Every change, whichever door it came through (MQTT, the
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

import logging
from abc import ABC, abstractmethod
from typing import Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel

from secuav_common.controlplane.payloads import RequestError, Verdict
from secuav_common.controlplane.topics import Scope
from secuav_common.loading import InputError

log = logging.getLogger(__name__)

StateT = TypeVar("StateT", bound=BaseModel)

__all__ = ["RequestError", "StateT", "Switch", "Verdict"]


class Switch(ABC, Generic[StateT]):
    """One runtime switch; subclasses say what they hold (:meth:`current`) and how a request changes it."""

    kind: ClassVar[str]  # the topic leaf: attack, attack/mode, secure, routes
    scope: ClassVar[Scope] = "vehicle"  # or "proxy": one per process, on secuav/proxy/<instance>/<kind>/...
    state_model: ClassVar[type[BaseModel]]  # what .../state carries (secuav_common.controlplane.payloads)
    bare_words: ClassVar[frozenset[bytes]] = frozenset()  # accepted without JSON quotes (``mosquitto_pub -m off``)

    def __init__(self) -> None:
        self.verdict = Verdict()

    def prepare(self, payload: Any, source: str) -> Any:
        """The costly, pure part of checking a request (parsing a profile), run off the event loop by the
        MQTT session; what it returns is what :meth:`apply` gets. Raises ``RequestError``/``InputError``."""
        return payload

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
            self.apply(payload, source)
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

"""What a runtime switch is on the wire, and nothing else: its kind, scope, state and request models.

A switch has three audiences, each in its own room, importing one way:

- the wire contract (this module, and one small module per switch in
  :mod:`secuav_common.controlplane.switches`): the topic leaf, the scope, what
  ``.../state`` carries and what ``.../set`` must hold; whoever speaks the plane
  (the proxy, the console, ``secuav-attack``, the simulator) reads it, and it
  imports nothing of the project above ``secuav_common``;
- the proxy's side (:mod:`mitm_proxy.control`): one :class:`~mitm_proxy.control.switch.Switch`
  class per kind, wrapping its stage and naming its contract;
- the command-line verbs (:mod:`mitm_proxy.tools.verbs`), with the CLI that owns the
  ``secuav-attack`` parser.

The request model is the one check a request meets before its switch sees it, in the proxy and in the
console alike (:meth:`SwitchContract.check`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from secuav_common.controlplane.topics import Scope

__all__ = ["SwitchContract"]


@dataclass(frozen=True, slots=True)
class SwitchContract:
    """One runtime switch on the wire.

    ``kind`` is the topic leaf (``secuav/v<N>/<kind>/set`` and ``.../state``); ``scope`` is ``vehicle``
    (one per link) or ``proxy`` (one per process, on ``secuav/proxy/[<instance>/]<kind>/...``);
    ``bare_words`` are accepted without JSON quotes (``mosquitto_pub -m off``).
    """

    kind: str
    scope: Scope
    state_model: type[BaseModel]
    request_model: type[BaseModel]
    bare_words: frozenset[bytes] = frozenset()

    @property
    def state_leaf(self) -> str:
        return f"{self.kind}/state"

    def check(self, payload: Any) -> BaseModel:
        """``payload`` (decoded JSON) as the request model; raises pydantic's ``ValidationError``."""
        if isinstance(payload, self.request_model):
            return payload
        return self.request_model.model_validate(payload)

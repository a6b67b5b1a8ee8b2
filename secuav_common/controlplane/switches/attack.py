"""``attack``: the active attack profile of one link (``secuav/v<N>/attack/set``, retained ``.../state``)."""

from __future__ import annotations

from typing import Any

from pydantic import RootModel, model_validator
from pydantic_core import PydanticCustomError

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.states import AttackState


class AttackRequest(RootModel[dict[str, Any] | str | None]):
    """``.../attack/set``: a profile (an object, or its YAML/JSON text), ``{"library": NAME, "parameters":
    {...}}``, or ``null`` to clear. The profile grammar is the attack library's: the proxy checks the profile
    itself when it builds it (the contract, below every library, only says what shape travels)."""

    @model_validator(mode="before")
    @classmethod
    def _shape(cls, value: Any) -> Any:
        if value is not None and not isinstance(value, dict | str):
            raise PydanticCustomError("attack_request", 'expected a profile (an object or its text), '
                                      '{"library": NAME, "parameters": {...}} or null')  # fmt: skip
        return value


CONTRACT = SwitchContract(kind="attack", scope="vehicle", state_model=AttackState, request_model=AttackRequest)

"""``secure``: the secure stage's estimator on one link (``secuav/v<N>/secure/set``, retained ``.../state``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, model_validator
from pydantic_core import PydanticCustomError

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.states import SecureState

ParamValue = bool | int | float | str
Direction = Literal["downlink", "uplink", "both"]


class SecureRequest(BaseModel):
    """``.../secure/set``: ``null`` or ``"off"``, an estimator's name, or an object. Fields left out keep
    their value; the stage's tuning fields (``group``, ``rate_hz``...: docs/interfaces.md) pass through to the
    stage's own configuration, which checks them."""

    model_config = ConfigDict(extra="allow")

    estimator: str | None = None
    params: dict[str, ParamValue] | None = None
    direction: Direction | None = None
    request_id: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _word(cls, value: Any) -> Any:
        if value is None or isinstance(value, str):
            return {"estimator": value}
        if not isinstance(value, dict):
            raise PydanticCustomError("secure_request", "expected null, 'off', an estimator name or an object")
        return value

    def fields(self) -> dict[str, Any]:
        """What the request sets (``request_id`` is the transport's)."""
        return {k: v for k, v in self.model_dump(exclude_unset=True).items() if k != "request_id"}


CONTRACT = SwitchContract(kind="secure", scope="vehicle", state_model=SecureState, request_model=SecureRequest,
                          bare_words=frozenset({b"off"}))  # fmt: skip

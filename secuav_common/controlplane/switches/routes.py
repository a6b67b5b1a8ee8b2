"""``routes``: the endpoints' routing rules of one proxy (``secuav/proxy/[<instance>/]routes/set``).

Proxy-wide: a request on ``secuav/proxy/routes/set`` reaches every proxy, one on
``secuav/proxy/<instance>/routes/set`` that instance; each answers on its own
``secuav/proxy/<instance>/routes/state``. The rules' grammar is the proxy's (docs/routes.md).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, field_validator, model_validator
from pydantic_core import PydanticCustomError

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.states import RoutesState


class RoutesRequest(BaseModel):
    """``.../routes/set``: ``{"endpoints": {"<name or URL>": <rules> | null, ...}}``; ``null`` lifts every rule
    of that endpoint, endpoints left out keep theirs."""

    model_config = ConfigDict(extra="forbid")

    endpoints: dict[str, dict[str, Any] | None]
    request_id: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _object(cls, value: Any) -> Any:
        return value if isinstance(value, dict) else {"endpoints": value}  # said as the endpoints it lacks

    @field_validator("endpoints", mode="wrap")
    @classmethod
    def _some(cls, value: Any, handler: Any) -> Any:
        if not isinstance(value, dict) or not value:
            raise PydanticCustomError("endpoints", 'expected {"endpoints": {"<name>": {rules} or null, ...}}')
        return handler(value)


CONTRACT = SwitchContract(kind="routes", scope="proxy", state_model=RoutesState, request_model=RoutesRequest)

"""``attack/mode``: the attack stage on, or bypassed with its profile kept (``secuav/v<N>/attack/mode/set``)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, field_validator, model_validator
from pydantic_core import PydanticCustomError

from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.states import MODES, Mode, ModeState


class ModeRequest(BaseModel):
    """``.../attack/mode/set``: ``"on"`` or ``"bypass"``, bare or as ``{"mode": ...}``."""

    model_config = ConfigDict(extra="forbid")

    mode: Mode
    request_id: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _bare(cls, value: Any) -> Any:
        return value if isinstance(value, dict) else {"mode": value}

    @field_validator("mode", mode="wrap")
    @classmethod
    def _one_of(cls, value: Any, handler: Any) -> Any:
        if value not in MODES:
            raise PydanticCustomError("mode", "must be " + " or ".join(f'"{m}"' for m in MODES))
        return handler(value)


CONTRACT = SwitchContract(kind="attack/mode", scope="vehicle", state_model=ModeState, request_model=ModeRequest,
                          bare_words=frozenset(m.encode() for m in MODES))  # fmt: skip

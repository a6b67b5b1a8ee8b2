"""What each runtime switch's retained ``.../state`` carries, and the verdict every one of them reports.

Beside the switches' contracts (``secuav_common/controlplane/switches/``), which name these models, and
below :mod:`secuav_common.controlplane.payloads`, which hands them on with the other topics' models.
"""

from __future__ import annotations

from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict

__all__ = ["MODES", "AttackState", "Mode", "ModeState", "RouteEntry", "RoutesState", "SecureState", "Verdict"]


class _Payload(BaseModel):
    """Fields a consumer relies on are required; the rest is optional, and unknown ones pass through."""

    model_config = ConfigDict(extra="allow")


class Verdict(BaseModel):
    """The verdict on the last request to a switch: its id, whether it was accepted, and why not."""

    model_config = ConfigDict(frozen=True)

    request_id: str | None = None
    ok: bool = True
    error: str | None = None


# Each state below lists its fields in the order they go on the wire (docs/interfaces.md), the verdict's
# three among them; a switch builds it from what is in force and its one Verdict.


class AttackState(_Payload):
    """``secuav/v<N>/attack/state`` (retained)."""

    sysid: int
    profile: str | None = None  # active profile name; None when no profile is active
    hash: str | None = None
    since: float | None = None  # wall-clock time (epoch s) the active profile was installed
    # Which way its rules change frames: "downlink" (toward the ground), "uplink" (toward the vehicle)
    directions: list[str] = []
    # What keeps the profile from acting fully, as "code: text": signed frames and no key
    # (attack.signed_no_key), carriers of an attacked quantity it leaves true (attack.true_copy)
    warnings: list[str] = []
    request_id: str | None = None  # of the last request, accepted or not
    ok: bool = True  # whether the last request was accepted
    error: str | None = None  # why it was rejected


Mode = Literal["on", "bypass"]  # the attack stage's two modes, spelled here only
MODES: tuple[str, ...] = get_args(Mode)


class ModeState(_Payload):
    """``secuav/v<N>/attack/mode/state`` (retained)."""

    sysid: int
    mode: Mode
    since: float | None = None
    request_id: str | None = None
    ok: bool = True
    error: str | None = None


class SecureState(_Payload):
    """``secuav/v<N>/secure/state`` (retained); ``available`` false: this proxy has no secure stage."""

    sysid: int
    ok: bool = True
    estimator: str | None = None
    params: dict[str, Any] = {}
    group: str | None = None
    direction: str | None = None  # where the stage reads its group and substitutes: downlink, uplink or both
    request_id: str | None = None
    error: str | None = None
    since: float | None = None
    available: bool = True
    warnings: list[str] = []  # what keeps the stage from working (e.g. the layout does not fit): "code: text"


class RouteEntry(_Payload):
    url: str
    role: Literal["vehicle", "ground"]
    rules: dict[str, Any] = {}


class RoutesState(_Payload):
    """``secuav/proxy/<instance>/routes/state`` (retained)."""

    instance: str
    since: float | None = None
    endpoints: dict[str, RouteEntry] = {}
    request_id: str | None = None
    ok: bool = True
    error: str | None = None

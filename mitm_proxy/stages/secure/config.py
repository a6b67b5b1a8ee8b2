"""What the secure stage runs: estimator, parameters, sensor group, stepping rule.

One pydantic model serves every way of configuring it (the proxy config file,
``--secure NAME``, MQTT ``secuav/v<sysid>/secure/set``), so a bad request is
refused the same way everywhere: one line naming the source, the field and the
value (:class:`secuav_common.loading.InputError`). ``estimator`` None is the
seed's bypass ("off").
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from secuav_common.controlplane.switches.secure import SecureRequest
from secuav_common.loading import first_error, validate

Group = Literal["auto", "wall", "anchors"]
ParamValue = bool | int | float | str
OFF_WORDS = frozenset({"off", "none", "bypass", ""})


class SecureConfig(BaseModel):
    """The secure stage of one link (one vehicle)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    estimator: str | None = Field(None, description="estimators.names() entry; None or 'off' = bypass")
    params: dict[str, ParamValue] = Field(
        default_factory=dict, description="keyword parameters of the estimator (s, alpha, q_mps2, window, ...)"
    )
    group: Group = Field(
        "auto", description="sensor group: the wall rangefinder group (ids 0-9) or the UWB anchors (10-49)"
    )
    noise_std_m: Annotated[float, Field(gt=0.0)] | None = Field(
        None, description="override the scenario's range noise std for the model"
    )
    direction: Literal["downlink", "uplink", "both"] = Field(
        "downlink",
        description="where the group's readings are read and the estimate substituted: downlink (what the vehicle "
        "sends, toward the ground), uplink (what the autopilot receives: a companion's rangefinders, UWB ranges) "
        "or both; the vehicle's ATTITUDE, velocity and home are read from the downlink whichever it is",
    )
    dims: Literal[2, 3] = Field(
        3,
        description="anchors: 3 = full NED, the downward laser one more reading the estimator weighs; "
        "2 = (north, east) with the laser's height taken as known",
    )
    tilt: bool = Field(
        True, description="wall group: project each reading on the wall's normal with the vehicle's ATTITUDE "
        "(a pitched beam reads d / cos); off for gimballed sensors"
    )
    rate_hz: Annotated[float, Field(gt=0.0, le=1000.0)] | None = Field(
        None, description="step at this rate on the latest readings; None = step when a set is complete"
    )
    max_wait_s: Annotated[float, Field(gt=0.0, le=10.0)] = Field(
        0.25, description="step an incomplete set this long after its first reading (a dropped sensor is NaN)"
    )
    max_age_s: Annotated[float, Field(gt=0.0, le=10.0)] = Field(
        0.5, description="a reading older than this counts as missing (NaN)"
    )
    asynchronous: bool = Field(
        True,
        description="each reading at its own time (reading_time): the EKF by sequential updates, the others on the "
        "readings of the last max_age_s brought to the step's time with the motion model (estimators.aligned); "
        "false: a set's readings are taken as simultaneous",
    )
    reading_time: Literal["stamp", "arrival"] = Field(
        "stamp",
        description="when a reading counts as taken: stamp = its time_boot_ms mapped onto the proxy's clock per "
        "sender (least offset over 2 s; a reboot or a time jump re-anchors; no stamp: its arrival), so delays, "
        "batching and replays cannot make it look newer; arrival = when it reached the proxy",
    )
    peer_gate_m: Annotated[float, Field(gt=0.0)] = Field(
        0.5, description="an inter-vehicle range further than this from the secure positions' distance is flagged"
    )
    executor: Literal["auto", "inline", "thread"] = Field(
        "auto",
        description="inline: step on the forwarding path; thread: in a worker, latest estimate wins; "
        "auto: inline while the smoothed step time stays under step_budget_s, else the worker",
    )
    step_budget_s: Annotated[float, Field(gt=0.0, le=1.0)] = Field(
        0.002, description="auto: longest smoothed step the forwarding path may wait for"
    )

    @field_validator("estimator", mode="before")
    @classmethod
    def _off(cls, value: Any) -> Any:
        if isinstance(value, str) and value.strip().lower() in OFF_WORDS:
            return None
        return value

    @property
    def enabled(self) -> bool:
        return self.estimator is not None


OFF = SecureConfig()


def config_from_payload(payload: Any, source: str = "<mqtt>", base: SecureConfig | None = None) -> SecureConfig:
    """The configuration a ``secure/set`` request (or ``--secure``, or the config file's ``secure:``) makes:
    ``null``/``"off"``, a name, or an object of :class:`SecureConfig` fields, read by the switch's request
    model (:class:`~secuav_common.controlplane.switches.secure.SecureRequest`), the one check of its shape.

    Fields the payload leaves out keep the values of ``base`` (the configured
    stage), except ``params``, which a new estimator name resets: parameters of
    one estimator rarely mean the same for another. ``request_id`` is the
    transport's business and ignored here.
    """
    try:
        request = payload if isinstance(payload, SecureRequest) else SecureRequest.model_validate(payload)
    except ValidationError as exc:
        raise first_error(exc, source) from None
    data = request.fields()
    if base is not None:
        merged = base.model_dump()
        if "estimator" in data and data["estimator"] != base.estimator and "params" not in data:
            merged["params"] = {}
        merged.update(data)
        data = merged
    return validate(SecureConfig, data, source)

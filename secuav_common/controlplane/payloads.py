"""What travels on each topic: pydantic models shared by whoever publishes and whoever reads.

A consumer decodes a message with :func:`decode` (raw bytes) or :func:`validate`
(JSON already parsed): the model of the topic, or :class:`PayloadError` naming
the topic, the field and the bad value, so a bad message is counted and
skipped while the rest flows. Models allow fields they do not know (a newer
proxy may add some); the ones they name are checked.

The proxy's own request decoding (:func:`loads_request`: size first, then
UTF-8, then JSON, and the ``request_id``) and the compact, strict JSON every
proxy message is written with (:func:`dumps`) live here too, so a request is
read the same way whichever switch it is for.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
from functools import cache
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from secuav_common.controlplane.states import (  # noqa: F401  (the switches' states, handed on with the rest)
    MODES,
    AttackState,
    Mode,
    ModeState,
    RouteEntry,
    RoutesState,
    SecureState,
    Verdict,
)
from secuav_common.controlplane.topics import Topic, parse

MAX_PAYLOAD_BYTES = 64 * 1024  # a set request larger than this is refused unread
MAX_MESSAGE_BYTES = 256 * 1024  # a consumer skips anything larger without decoding it
# The largest MQTT packet (a message, its topic and headers) a broker we configure takes and a client of ours
# reads; a packet that declares more is refused on its fixed header, before its body is read.
MAX_PACKET_BYTES = MAX_MESSAGE_BYTES + 4096

# A request id the CLI puts first in its JSON, so an oversized or broken payload can still be answered.
_REQUEST_ID_PREFIX = re.compile(rb'\A\s*\{\s*"request_id"\s*:\s*"([A-Za-z0-9_.:@/-]{1,100})"')


class RequestError(ValueError):
    """A set request refused before or while it was applied; the message is what the state reports."""


class PayloadError(ValueError):
    """A message that does not fit its topic's model: says the topic, the field and the value."""


class _Payload(BaseModel):
    """Fields a consumer relies on are required; the rest is optional, and unknown ones pass through (as
    :mod:`~secuav_common.controlplane.states` does for the switches' states)."""

    model_config = ConfigDict(extra="allow")


class ProxyOnline(_Payload):
    """``secuav/proxy/<instance>/online`` (retained, and the last will with ``online`` false)."""

    instance: str
    online: bool
    since: float | None = None
    vehicles: list[int] = []


class ConsoleOnline(_Payload):
    """``secuav/console/<id>/online`` (retained, and the last will with ``online`` false)."""

    id: str
    online: bool
    url: str | None = None
    since: float | None = None


class DirectionStats(_Payload):
    frames_in: int = 0
    frames_out: int = 0
    rewritten: int = 0
    dropped: int = 0
    bad_total: int = 0


class LinkStatsMessage(_Payload):
    """``secuav/v<N>/stats`` (1 Hz)."""

    downlink: DirectionStats | None = None
    uplink: DirectionStats | None = None
    latency_ms: dict[str, float | int | None] = {}
    warnings: list[str] = []  # the attack/state and secure/state warnings of the link, "code: text"


class EstimateMessage(_Payload):
    """``secuav/v<N>/estimate``; NaN travels as null."""

    sysid: int
    estimator: str | None = None
    sim_t_s: float | None = None
    ok: bool | None = None
    alarm: bool | None = None
    valid: bool | None = None
    attacked: list[int] = []
    used: list[int] = []
    step_time_s: float | None = None
    readings_m: list[float | None] = []
    sensor_ids: list[int] = []
    position_ned_m: list[float | None] | None = None
    distance_m: float | None = None


class Truth(_Payload):
    """``secuav/v<N>/truth`` from ``secuav-sim`` (evaluation only: estimators never read it)."""

    t_s: float | None = None
    sysid: int | None = None
    pos_ned_m: Annotated[list[float], Field(min_length=3, max_length=3)]
    vel_ned_m_s: list[float] | None = None
    euler_rad: list[float] | None = None
    quat: list[float] | None = None
    collided: bool = False


class SensorReading(_Payload):
    original_m: float | None = None
    attacked_m: float | None = None
    forwarded_m: float | None = None
    flagged: bool = False


class ReadingsMessage(_Payload):
    """``secuav/v<N>/readings`` (10 Hz while a console watches)."""

    sysid: int | None = None
    t: float | None = None
    sensors: dict[str, SensorReading] = {}
    position: dict[str, list[float | None] | None] | None = None


# (scope, leaf, verb) -> what the message holds; a leaf not listed here is not checked. A switch's state
# and request are the switch's own contract: secuav_common/controlplane/switches/.
MODELS: dict[tuple[str, str, str | None], Any] = {
    ("vehicle", "stats", None): LinkStatsMessage,
    ("vehicle", "estimate", None): EstimateMessage,
    ("vehicle", "truth", None): Truth,
    ("vehicle", "readings", None): ReadingsMessage,
    ("proxy", "online", None): ProxyOnline | bool,  # the instance record; the proxy-wide flag is a bare bool
    ("console", "online", None): ConsoleOnline,
}


@cache
def _adapter(kind: Any) -> TypeAdapter[Any]:
    return TypeAdapter(kind)


def model_for(topic: Topic) -> Any | None:
    """The model of a parsed topic's payload, or ``None`` when the grammar gives it none."""
    if topic.scope == "proxy" and topic.leaf == "online" and topic.key is None:
        return bool
    if topic.verb is not None:
        from secuav_common.controlplane.switches import find  # the switches' contracts import the models above

        spec = find(topic.scope, topic.leaf)
        if spec is not None:
            return spec.state_model if topic.verb == "state" else spec.request_model
    return MODELS.get((topic.scope, topic.leaf, topic.verb))


def validate(topic: str | Topic, body: Any) -> Any:
    """``body`` (parsed JSON) checked against its topic's model: the model instance (the body itself for a
    topic without one); :class:`PayloadError` if it does not fit."""
    parsed = parse(topic) if isinstance(topic, str) else topic
    kind = None if parsed is None else model_for(parsed)
    if kind is None:
        return body
    name = topic if isinstance(topic, str) else topic.with_verb(topic.verb)
    try:
        return _adapter(kind).validate_python(body)
    except ValidationError as exc:
        raise PayloadError(f"{name}: {error_text(exc)}") from None


def error_text(exc: ValidationError, prefix: str = "", model: type[BaseModel] | None = None) -> str:
    """The first error of ``exc`` as one line, ``<field>: <why> (got <value>)``, the field after ``prefix``:
    how every refused message or request on the plane says what was wrong (a field ``model`` does not know
    is named with the ones it does)."""
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"])
    where = prefix + where if where else prefix.rstrip(".") or "(payload)"
    if err["type"] == "extra_forbidden" and model is not None and len(err["loc"]) == 1:
        return f"{where}: unknown field (known: {', '.join(model.model_fields)})"
    value = json.dumps(err.get("input"), default=str)[:60]
    return f"{where}: {err['msg']} (got {value})"


def decode(topic: str | Topic, raw: bytes | bytearray) -> Any:
    """A received message: size, JSON and its topic's model checked; :class:`PayloadError` says why not."""
    name = topic if isinstance(topic, str) else topic.with_verb(topic.verb)
    if len(raw) > MAX_MESSAGE_BYTES:
        raise PayloadError(f"{name}: payload of {len(raw)} bytes is larger than {MAX_MESSAGE_BYTES} bytes")
    try:
        body = json.loads(raw) if raw else None
    except (ValueError, RecursionError) as exc:
        raise PayloadError(f"{name}: payload is not JSON ({str(exc)[:80]})") from None
    return validate(topic, body)


def as_dict(message: Any) -> Any:
    """A decoded message as plain JSON data (what a page or a table reads): the fields it carried, no more."""
    return message.model_dump(mode="json", exclude_unset=True) if isinstance(message, BaseModel) else message


# -- requests, as the proxy reads them ----------------------------------------------------------------


def loads_request(raw: bytes) -> tuple[Any, str | None]:
    """JSON payload of a ``.../set`` and its ``request_id``; :class:`RequestError` says why it is refused.

    The size is checked before anything is decoded, so a flood of huge
    messages costs a length comparison each.
    """
    if len(raw) > MAX_PAYLOAD_BYTES:
        raise RequestError(f"payload of {len(raw)} bytes is larger than {MAX_PAYLOAD_BYTES} bytes")
    if not raw.strip():
        raise RequestError("empty payload; send JSON null to clear")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RequestError(f"payload is not UTF-8 text (byte {exc.start})") from None
    try:
        payload = json.loads(text)
    except (ValueError, RecursionError) as exc:
        where = f" at line {exc.lineno} column {exc.colno}" if isinstance(exc, json.JSONDecodeError) else ""
        if isinstance(exc, json.JSONDecodeError):
            reason = exc.msg
        elif isinstance(exc, RecursionError):
            reason = "nested too deeply"
        else:  # e.g. an integer of thousands of digits (Python's int parsing limit)
            reason = str(exc).split(";")[0]
        raise RequestError(f"payload is not JSON: {reason}{where}") from None
    request_id = payload.get("request_id") if isinstance(payload, dict) else None
    if request_id is not None and not isinstance(request_id, str):
        request_id = json.dumps(request_id)[:100]
    return payload, request_id


def salvage_request_id(raw: bytes) -> str | None:
    """The request id of a refused payload, when it leads the JSON object (as ``secuav-attack`` writes it)."""
    m = _REQUEST_ID_PREFIX.match(raw[:200])
    return m.group(1).decode() if m else None


def request_bytes(body: Any, request_id: str) -> bytes:
    """A ``.../set`` request: ``body`` (an object, or None for "clear") with ``request_id`` leading the JSON."""
    payload = {"request_id": request_id, **body} if isinstance(body, dict) else {"request_id": request_id}
    return json.dumps(payload).encode()


# -- writing ------------------------------------------------------------------------------------------


def _finite(node: Any) -> Any:
    """NaN and infinities as JSON null: estimates mark missing readings with NaN, and JSON has no NaN."""
    if isinstance(node, float) and not math.isfinite(node):
        return None
    if isinstance(node, dict):
        return {k: _finite(v) for k, v in node.items()}
    if isinstance(node, list | tuple):
        return [_finite(v) for v in node]
    return node


def _plain(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json", exclude_unset=True)
    item = getattr(value, "item", None)  # numpy scalar -> Python number
    if callable(item):
        with contextlib.suppress(Exception):
            plain = item()
            return None if isinstance(plain, float) and not math.isfinite(plain) else plain
    tolist = getattr(value, "tolist", None)  # numpy array -> list
    if callable(tolist):
        with contextlib.suppress(Exception):
            return _finite(tolist())
    return str(value)


def dumps(payload: Any) -> bytes:
    """Compact, strict JSON (bytes pass through); models (the fields they were given, in their declared
    order), numpy scalars and arrays become plain JSON."""
    if isinstance(payload, bytes):
        return payload
    if isinstance(payload, BaseModel):
        payload = payload.model_dump(mode="json", exclude_unset=True)
    try:
        return json.dumps(payload, separators=(",", ":"), allow_nan=False, default=_plain).encode()
    except ValueError:  # a NaN somewhere: the slow path only then
        return json.dumps(_finite(payload), separators=(",", ":"), allow_nan=False, default=_plain).encode()

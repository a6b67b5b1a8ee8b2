"""What every rule has, whatever its primitive: a target and a time window.

Each primitive module (``attack_profiles/primitives/*.py``) subclasses
:class:`RuleBase` with its ``kind`` tag and its parameters; the profile model
joins them into one discriminated union on ``kind``. Parameters are in physical
units of the targeted field (metres, m/s, degrees; see :mod:`attack_profiles.units`).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from attack_profiles.quantities import COMPONENTS, DATUM_QUANTITIES, DEFAULT_COMPONENT, QuantityName
from attack_profiles.units import MESSAGES, MessageSpec
from attack_profiles.where import check_field, check_where
from secuav_common.loading import (
    _MISSING,  # the "no value to show" sentinel InputError understands
    InputError,
)


def _known_message(name: str) -> str:
    """A message of the common or ardupilotmega dialect (the typed ones are known without importing it)."""
    if name in MESSAGES:
        return name
    from attack_profiles import dialect

    if dialect.message(name) is None:
        near = dialect.closest(name, dialect.message_names())
        raise ValueError("no such MAVLink message in the common or ardupilotmega dialect" + (f"; {near}" if near
                                                                                             else ""))  # fmt: skip
    return name


# A string checked against the dialect, not an enum of its 300 names: the schema stays readable.
MessageName = Annotated[str, AfterValidator(_known_message)]
WhereValue = int | Annotated[float, Field(allow_inf_nan=False)] | str
DirectionName = Literal["downlink", "uplink", "both"]
SensorId = Annotated[int, Field(ge=0, le=255)]
Seconds = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
Vec3Param = tuple[Finite, Finite, Finite]


class Strict(BaseModel):
    """Unknown keys are errors, values are immutable, NaN and infinity are refused
    (they would not survive a JSON round trip and never make sense as a parameter)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class IdRange(Strict):
    """An inclusive range of sensor ids, e.g. the eight anchor links ``{first: 10, last: 17}``."""

    first: SensorId
    last: SensorId


class Target(Strict):
    """Which values a rule acts on: one ``message``, or one ``quantity`` wherever it travels.

    ``quantity`` (rangefinder, altitude, position) rewrites every message that
    carries it, the same way (see the mapping table in docs/profile.md); its
    ``field`` is the component: ``distance`` (rangefinder, the default), ``up``
    (altitude, the default), ``north`` or ``east`` (position, one must be named).
    ``sensor_id`` (a single id, a list, or an inclusive range) only applies to
    messages that carry one (DISTANCE_SENSOR's ``id``) and to the rangefinder
    quantity; leaving it out targets every sensor. ``field`` defaults to the
    message's main field where it has one (DISTANCE_SENSOR: ``current_distance``);
    drop, delay and intermittent act on whole frames and ignore it. ``sysid``
    left out targets every vehicle.

    ``message`` is any message of the common or ardupilotmega dialect, ``field``
    any of its numeric fields, an array element as ``name[i]`` (units and scaling
    from the dialect: :mod:`attack_profiles.dialect`). ``where`` restricts the
    rule to frames whose other fields have given values, e.g. ``{command:
    MAV_CMD_NAV_TAKEOFF}`` or ``{param_id: RTL_ALT}``.
    """

    message: MessageName | None = Field(
        None,
        description="one message of the common or ardupilotmega dialect (e.g. DISTANCE_SENSOR, COMMAND_LONG); "
        "or give quantity",
    )
    quantity: QuantityName | None = Field(None, description="every message that carries it; or give message")
    sensor_id: SensorId | list[SensorId] | IdRange | None = None
    field: str | None = None
    direction: DirectionName = "downlink"
    sysid: Annotated[int, Field(ge=0, le=255)] | None = None
    where: dict[str, WhereValue | list[WhereValue]] | None = Field(
        None,
        description="act only on frames whose other fields have these values (a list: any of them): numbers in the "
        "field's physical unit, enum entry names (MAV_CMD_NAV_TAKEOFF or NAV_TAKEOFF), text for char fields "
        "(param_id)",
    )

    def sensor_ids(self) -> frozenset[int] | None:
        """The targeted ids, or ``None`` for every sensor."""
        sid = self.sensor_id
        if sid is None:
            return None
        if isinstance(sid, int):
            return frozenset((sid,))
        if isinstance(sid, IdRange):
            return frozenset(range(sid.first, sid.last + 1))
        return frozenset(sid)


class RuleBase(Strict):
    """Target and window shared by every rule.

    The rule is active while ``start_s <= t < end_s`` on the profile's clock
    (no ``end_s``: until the profile is cleared). With ``repeat_period_s`` the
    window recurs: active while ``(t - start_s) mod repeat_period_s`` is below
    ``end_s - start_s``. Time-varying primitives measure their own time ``tau``
    from the start of the current window occurrence.
    """

    target: Target
    start_s: Seconds = 0.0
    end_s: Seconds | None = None
    repeat_period_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)] | None = None
    note: str = Field("", description="free text, e.g. why this rule exists")
    out_of_range: Literal["keep", "attack"] = Field(
        "keep",
        description="keep: a reading the sensor flags as no reading (outside [min, max], invalid quality, no fix) "
        "passes unchanged and an attacked reading stays inside the sensor's [min, max]; attack: both are attacked",
    )

    # Drop, delay and intermittent act on whole frames: their target needs no field.
    frame_level: ClassVar[bool] = False
    # The sample must carry the vehicle's position as the attacker reads it (the engine then
    # decodes LOCAL_POSITION_NED too), or the scenario's anchor positions.
    needs_position: ClassVar[bool] = False
    needs_anchors: ClassVar[bool] = False
    # Garbage models a sensor gone mad: it ignores out_of_range and the sensor's limits.
    within_limits: ClassVar[bool] = True
    # What the rule writes is kept inside the sensor's [min, max] (set writes what the profile says).
    clamps_to_limits: ClassVar[bool] = True

    def fields_of(self, msg: MessageSpec) -> list[str | None]:
        """The fields this rule rewrites (``[None]``: the frame as a whole)."""
        if self.frame_level:
            return [None]
        return [self.target.field or msg.default_field]

    def names_a_field(self) -> bool:
        """Whether a message target must name a field when the message has no main one."""
        return not self.frame_level

    def check(self, where: str, source: str) -> None:
        """What the schema cannot express; raises ``InputError`` at ``where`` (``rules[2]``).

        Primitives with cross-field constraints extend this (and call it first).
        """
        target = self.target
        kind = getattr(self, "kind", "?")
        if (target.message is None) == (target.quantity is None):
            given = None if target.message is None else f"{target.message} and {target.quantity}"
            raise InputError(source, f"{where}.target", given or _MISSING, "give exactly one of message and quantity")
        if target.quantity is not None:
            self._check_quantity(where, source, kind)
        else:
            self._check_message(where, source, kind)
        self._check_window(where, source)

    def _check_quantity(self, where: str, source: str, kind: str) -> None:
        target = self.target
        q = target.quantity
        assert q is not None
        comps = ", ".join(COMPONENTS[q])
        if target.field is not None and target.field not in COMPONENTS[q]:
            raise InputError(source, f"{where}.target.field", target.field, f"not a component of {q} ({comps})")
        if not self.frame_level and target.field is None and DEFAULT_COMPONENT[q] is None:
            raise InputError(source, f"{where}.target.field", _MISSING, f"{kind} on {q} needs one of {comps}")
        if target.sensor_id is not None and q != "rangefinder":
            raise InputError(source, f"{where}.target.sensor_id", target.sensor_id, f"{q} has no sensor id")
        if target.where is not None:
            raise InputError(source, f"{where}.target.where", target.where, "where needs a message target")
        if q in DATUM_QUANTITIES and kind in ("set", "scale", "garbage"):
            raise InputError(source, f"{where}.kind", kind, f"{q} travels in several datums (AMSL, home, local): "
                             "only offsets, noise and frame rules are consistent across them")  # fmt: skip
        self._check_ids(where, source)

    def _check_message(self, where: str, source: str, kind: str) -> None:
        target = self.target
        assert target.message is not None
        spec = MESSAGES[target.message]
        if target.field is not None:
            check_field(spec, target.field, f"{where}.target.field", source)
        if target.where is not None:
            check_where(spec, target.where, f"{where}.target.where", source)
        if self.names_a_field() and target.field is None and spec.default_field is None:
            raise InputError(source, f"{where}.target.field", _MISSING, f"{kind} on {spec.name} needs a field")
        if target.sensor_id is not None and spec.id_field is None:
            raise InputError(source, f"{where}.target.sensor_id", target.sensor_id, f"{spec.name} has no sensor id")
        self._check_ids(where, source)

    def _check_ids(self, where: str, source: str) -> None:
        sid = self.target.sensor_id
        if sid is not None:
            if isinstance(sid, IdRange) and sid.last < sid.first:
                raise InputError(source, f"{where}.target.sensor_id.last", sid.last, f"below first ({sid.first})")
            if isinstance(sid, list) and not sid:
                raise InputError(source, f"{where}.target.sensor_id", sid, "empty id list; leave it out to target all")

    def _check_window(self, where: str, source: str) -> None:
        if self.end_s is not None and self.end_s <= self.start_s:
            raise InputError(
                source, f"{where}.end_s", self.end_s, f"window ends before it starts (start_s {self.start_s})"
            )
        if self.repeat_period_s is not None:
            if self.end_s is None:
                raise InputError(
                    source, f"{where}.repeat_period_s", self.repeat_period_s, "a repeating window needs end_s"
                )
            if self.repeat_period_s < self.end_s - self.start_s:
                length = self.end_s - self.start_s
                raise InputError(
                    source, f"{where}.repeat_period_s", self.repeat_period_s, f"shorter than the window ({length} s)"
                )

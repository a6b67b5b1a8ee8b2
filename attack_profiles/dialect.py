"""Any message, any field: specs derived from the MAVLink dialect, on first use.

``target.message`` may name any message of pymavlink's ardupilotmega
dialect, which includes common (COMMAND_LONG, COMMAND_INT,
PARAM_SET, SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT,
MISSION_ITEM_INT, VISION_POSITION_ESTIMATE, GPS_INPUT, HIL_GPS, ...), and
``target.field`` any numeric field of it. In the schema ``message`` is a
string checked against the dialect, not an enum of some 300 names. What pymavlink
generated from the XML gives each field its wire type, unit, enum and array
length; the table of a message is built the first time a profile names it, so
importing attack_profiles does not import the dialect, and a profile of
the fifteen typed messages (the mapping table above lists most of them) never
does. Where a typed message has a field in its own table, that entry wins; its
other fields come from the dialect like everyone else's.

- Units: a field whose XML unit is in the table below is written in the
  physical unit (``degE7`` -> deg, ``cm`` -> m, ``rad`` -> deg, ``ms`` -> s,
  ...): the value a rule writes is converted to the wire, rounded for integer
  fields. Any other unit, and a field the XML gives no unit, is written in wire
  units: COMMAND_LONG's ``param1`` .. ``param7`` are floats in whatever the
  command defines (NAV_TAKEOFF's ``param7``: metres); COMMAND_INT's and
  MISSION_ITEM_INT's ``x`` / ``y`` are integers, degrees x 1e7 in a global
  frame, metres x 1e4 in a local one.
- 64-bit integers are never scaled (``time_usec`` stays microseconds), so every
  integer field round-trips exactly: wire -> physical -> wire gives the wire value.
- Arrays by index: ``field: "distances[3]"`` (OBSTACLE_DISTANCE), ``q[0]``;
  the element is rewritten in place, the rest of the array is left as it came.
- Text (char arrays such as PARAM_SET's ``param_id``) is not a value a rule
  rewrites; ``where`` matches it.
- ``set`` on a derived field refuses a value the wire type cannot carry when
  the profile is read; the typed fields keep clamping at the wire, reported in
  ``Action.clamped``.
- ``sensor_id`` stays DISTANCE_SENSOR's (and the rangefinder quantity's); on
  other messages ``where`` picks frames by any field.

Takeoff altitude and a parameter, toward the vehicle::

    rules:
      - target: {message: COMMAND_LONG, field: param7, direction: uplink,
                 where: {command: MAV_CMD_NAV_TAKEOFF}}
        kind: set
        value: 12
      - target: {message: PARAM_SET, field: param_value, direction: uplink,
                 where: {param_id: RTL_ALT}}
        kind: set
        value: 300
      - target: {message: OBSTACLE_DISTANCE, field: "distances[3]"}
        kind: bias
        offset: 150

A wrong name, or a value the field cannot carry, is one line naming the
file, the place, the closest valid names and the value (below: what this
version prints).
"""

from __future__ import annotations

import difflib
from functools import cache
from types import ModuleType
from typing import Any

from attack_profiles.wire import DERIVED_UNITS, FieldSpec, MessageSpec, wire_range

_WIDE = frozenset({"uint64_t", "int64_t"})


@cache
def _dialect() -> ModuleType:
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


@cache
def _classes() -> dict[str, Any]:
    return {cls.msgname: cls for cls in _dialect().mavlink_map.values()}


def message_names() -> tuple[str, ...]:
    """Every message name of the dialect, sorted."""
    return tuple(sorted(_classes()))


def _field_spec(name: str, wire_type: str, wire_unit: str, enum: str | None) -> FieldSpec:
    lo, hi, integer = wire_range(wire_type)
    conversion = None if wire_type in _WIDE else DERIVED_UNITS.get(wire_unit)
    if conversion is None or (integer and conversion[0] == 1.0):
        scale: float = 1 if integer else 1.0  # an int 1 keeps integers exact
        unit = wire_unit
    else:
        scale, unit = conversion
    return FieldSpec(name, wire_type, wire_unit, scale, unit, lo, hi, integer, enum=enum)


@cache
def _tables(message: str) -> tuple[dict[str, FieldSpec], dict[str, int], dict[str, int]] | None:
    """(value fields with array elements, char fields -> length, arrays -> length) of ``message``."""
    cls = _classes().get(message)
    if cls is None:
        return None
    fields: dict[str, FieldSpec] = {}
    chars: dict[str, int] = {}
    arrays: dict[str, int] = {}
    for i, (name, wire_type) in enumerate(zip(cls.fieldnames, cls.fieldtypes, strict=True)):
        length = cls.array_lengths[cls.orders[i]]  # array_lengths is in wire order, fieldnames in the XML's
        if wire_type == "char":
            chars[name] = max(length, 1)
            continue
        wire_type = "uint8_t" if wire_type == "uint8_t_mavlink_version" else wire_type
        unit = cls.fieldunits_by_name.get(name, "")
        spec = _field_spec(name, wire_type, unit, cls.fieldenums_by_name.get(name))
        if length == 0:
            fields[name] = spec
            continue
        arrays[name] = length
        for i in range(length):
            element = f"{name}[{i}]"
            fields[element] = FieldSpec(element, spec.wire_type, spec.wire_unit, spec.scale, spec.unit, spec.lo,
                                        spec.hi, spec.integer, name, i, spec.enum)  # fmt: skip
    return fields, chars, arrays


def fields(message: str) -> dict[str, FieldSpec]:
    """Every numeric field of ``message`` (array elements as ``name[i]``); empty if there is no such message."""
    tables = _tables(message)
    return {} if tables is None else tables[0]


def char_fields(message: str) -> dict[str, int]:
    """The text fields of ``message`` and their lengths (``param_id``: 16)."""
    tables = _tables(message)
    return {} if tables is None else tables[1]


def arrays(message: str) -> dict[str, int]:
    """The numeric arrays of ``message`` and their lengths (``distances``: 72)."""
    tables = _tables(message)
    return {} if tables is None else tables[2]


@cache
def message(name: str) -> MessageSpec | None:
    """A derived spec of every field of ``name`` (typed messages too), or ``None`` if the dialect lacks it."""
    cls = _classes().get(name)
    if cls is None:
        return None
    table = fields(name)
    time_field = next((t for t in ("time_boot_ms", "time_usec") if t in table), None)
    return MessageSpec(name, int(cls.id), table, None, None, time_field, derived=True)


@cache
def enum_values(enum: str) -> dict[str, int]:
    """Entry name -> value of a MAVLink enum (``MAV_CMD_NAV_TAKEOFF`` -> 22); empty if unknown."""
    entries = _dialect().enums.get(enum, {})
    return {e.name: int(value) for value, e in entries.items() if not e.name.endswith("_ENUM_END")}


def enum_value(enum: str, name: str) -> int | None:
    """The value of ``name`` in ``enum``; the enum's prefix may be left out (``NAV_TAKEOFF`` for MAV_CMD)."""
    values = enum_values(enum)
    found = values.get(name)
    return values.get(f"{enum}_{name}") if found is None else found


def units_table() -> str:
    """The unit conversions of derived fields as Markdown, for docs/profile.md."""
    rows = ["| wire unit (XML) | profile unit | one wire unit is |", "|---|---|---|"]
    for wire_unit, (scale, unit) in DERIVED_UNITS.items():
        if wire_unit:
            rows.append(f"| `{wire_unit}` | {unit} | {scale:.6g} {unit} |")
    return "\n".join(rows) + "\n"


def closest(word: str, names: list[str] | tuple[str, ...], n: int = 3) -> str:
    """The text ``closest: A, B`` (difflib), or "" when nothing is near; case is ignored."""
    by_upper = {name.upper(): name for name in names}
    near = difflib.get_close_matches(word.upper(), list(by_upper), n=n, cutoff=0.5)
    return ("closest: " + ", ".join(by_upper[m] for m in near)) if near else ""

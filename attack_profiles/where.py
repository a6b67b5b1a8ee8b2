"""A target's field and its ``where``: checked against the dialect, resolved to wire values.

``where`` maps other fields of the message to the values a frame must carry
for the rule to act on it (every entry must hold; a list means any of its
values). A value is written like any value of a profile: a number in the
field's physical unit (``frame: 6``, ``lat: 47.397742``), an entry name of the
field's enum (``command: MAV_CMD_NAV_TAKEOFF``, or ``NAV_TAKEOFF`` without the
enum's prefix), or text for a char field (``param_id: RTL_ALT``). The engine
compares the frame's wire values with the wire values resolved here once, so a
float is compared as the float32 the frame carries.

A frame that does not match is not the rule's at all: stateful rules (freeze,
replay) do not see it either, and frame rules (drop, delay) leave it alone.
The test runs only on frames of the targeted message, after the message id
check every frame already passes; other traffic never reaches it. Offline
arrays (``Engine.apply_array``) carry only the attacked field, so a rule
whose ``where`` names another field does not act on them.

Drop the RTL and mode-change commands the ground sends, and no other::

    - target: {message: COMMAND_LONG, direction: uplink,
               where: {command: [MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_DO_SET_MODE]}}
      kind: drop
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

from attack_profiles.units import FieldSpec, MessageSpec
from secuav_common.loading import InputError

_F32 = struct.Struct("<f")
Match = tuple[tuple[str, frozenset[Any]], ...]  # (field, the wire values that match) per entry


def _names(msg: MessageSpec) -> list[str]:
    """Every field name a target may give: typed and derived, array elements, text fields."""
    from attack_profiles import dialect

    return list(dict.fromkeys([*msg.fields, *dialect.fields(msg.name), *dialect.char_fields(msg.name)]))


def _unknown(msg: MessageSpec, name: str) -> str:
    """Why ``name`` is no field of ``msg``, with the closest names."""
    from attack_profiles import dialect

    base, _, rest = name.partition("[")
    length = dialect.arrays(msg.name).get(base)
    if length is not None and not rest:
        return f"{msg.name}.{base} is an array of {length}: name an element, {base}[0] to {base}[{length - 1}]"
    if length is not None:
        return f"{msg.name}.{base} has {length} elements: {base}[0] to {base}[{length - 1}]"
    near = dialect.closest(name, [n for n in _names(msg) if "[" not in n] + list(dialect.arrays(msg.name)))
    return f"no such field of {msg.name}" + (f"; {near}" if near else "")


def check_field(msg: MessageSpec, name: str, path: str, source: str) -> FieldSpec:
    """The spec of the numeric field a rule rewrites; ``InputError`` naming the closest valid ones."""
    spec = msg.field(name)
    if spec is not None:
        return spec
    from attack_profiles import dialect

    if name in dialect.char_fields(msg.name):
        raise InputError(source, path, name, f"{msg.name}.{name} is text: a rule rewrites numbers (match it in where)")
    raise InputError(source, path, name, _unknown(msg, name))


def _key_path(path: str, key: str) -> str:
    return f"{path}.{key}" if key.isidentifier() else f"{path}[{key!r}]"


def _wire(msg: MessageSpec, spec: FieldSpec, value: Any, path: str, source: str) -> float | int:
    """One ``where`` value of a numeric field as the wire value a frame would carry."""
    from attack_profiles import dialect

    if isinstance(value, str):
        if spec.enum is None:
            raise InputError(source, path, value, f"{msg.name}.{spec.name} takes a number (the XML gives it no enum)")
        found = dialect.enum_value(spec.enum, value)
        if found is None:
            near = dialect.closest(value, list(dialect.enum_values(spec.enum)))
            raise InputError(source, path, value, f"not an entry of {spec.enum}" + (f"; {near}" if near else ""))
        value = found
    if isinstance(value, bool):
        value = int(value)
    wire, clamped = spec.to_wire(value)
    unit = f" {spec.unit}" if spec.unit else ""
    if clamped:
        lo, hi = sorted((spec.lo * spec.scale, spec.hi * spec.scale))
        raise InputError(source, path, value, f"outside what {spec.wire_type} carries: {lo:g} to {hi:g}{unit}")
    if spec.integer and abs(value / spec.scale - wire) > 1e-6:
        steps = f"steps of {spec.scale:g}{unit}"
        raise InputError(source, path, value, f"not a whole wire value ({spec.wire_type}, {steps})")
    if spec.wire_type == "float":
        wire = _F32.unpack(_F32.pack(wire))[0]  # what a decoded frame carries
    return wire


def resolve_where(msg: MessageSpec, where: Mapping[str, Any], path: str, source: str) -> Match:
    """``where`` as (field, wire values) pairs; ``InputError`` for a bad field or value."""
    from attack_profiles import dialect

    if not where:
        raise InputError(source, path, dict(where), "empty; leave where out to act on every frame")
    chars = dialect.char_fields(msg.name)
    out: list[tuple[str, frozenset[Any]]] = []
    for key, given in where.items():
        key_path = _key_path(path, key)
        values = given if isinstance(given, list) else [given]
        if not values:
            raise InputError(source, key_path, given, "empty list: give one value or several")
        paths = [f"{key_path}[{j}]" for j in range(len(values))] if isinstance(given, list) else [key_path]
        if key in chars:
            for value, at in zip(values, paths, strict=True):
                if not isinstance(value, str) or len(value) > chars[key]:
                    raise InputError(source, at, value, f"{msg.name}.{key} is text of up to {chars[key]} characters")
            out.append((key, frozenset(values)))
            continue
        spec = msg.field(key)
        if spec is None:
            raise InputError(source, key_path, key, _unknown(msg, key))
        out.append((key, frozenset(_wire(msg, spec, v, at, source) for v, at in zip(values, paths, strict=True))))
    return tuple(out)


def check_where(msg: MessageSpec, where: Mapping[str, Any], path: str, source: str) -> None:
    resolve_where(msg, where, path, source)


def matches(match: Match, fields: Mapping[str, Any]) -> bool:
    """Whether a frame's fields (wire units) satisfy every entry."""
    return all(fields.get(name) in allowed for name, allowed in match)

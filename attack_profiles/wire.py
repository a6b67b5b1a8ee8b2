"""The types of an attackable MAVLink field and message, and the wire types' ranges and units.

The ground floor of :mod:`attack_profiles.units` (the typed table) and :mod:`attack_profiles.dialect` (every other
message, derived from pymavlink): both build on these, and this module imports neither.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

# Representable ranges of the MAVLink wire types.
_INT_RANGE = {
    "uint8_t": (0, 2**8 - 1),
    "int8_t": (-(2**7), 2**7 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}
_FLOAT32_MAX = 3.4028234663852886e38
# The largest double that float32 packing still rounds to _FLOAT32_MAX (half an ulp above it): a value
# up to this one is the float32 maximum, brought back from a scaled unit with a last-bit error, not an overflow.
_FLOAT32_ROUNDS_TO_MAX = 3.4028235677973362e38

# Physical units per wire unit; the physical unit is what profiles are written in.
_UNIT = {
    "m": (1.0, "m"),
    "cm": (0.01, "m"),
    "mm": (0.001, "m"),
    "m/s": (1.0, "m/s"),
    "cm/s": (0.01, "m/s"),
    "mm/s": (0.001, "m/s"),
    "degE7": (1e-7, "deg"),
    "degE5": (1e-5, "deg"),
    "cdeg": (0.01, "deg"),
    "rad": (180.0 / math.pi, "deg"),
    "rad/s": (180.0 / math.pi, "deg/s"),
    "ms": (0.001, "s"),
    "us": (1e-6, "s"),
    "%": (1.0, "%"),
    "V": (1.0, "V"),
    "": (1.0, ""),
}
# Further units of the dialect with an unambiguous physical unit (used for derived fields only; a unit
# in neither table stays as the XML writes it, scale 1). "deg/2" and "m/s*5" are what the XML writes for
# HIGH_LATENCY2's packed fields: the wire carries degrees / 2 and m/s * 5.
DERIVED_UNITS: dict[str, tuple[float, str]] = {
    **_UNIT,
    "dm": (0.1, "m"),
    "dam": (10.0, "m"),
    "dm/s": (0.1, "m/s"),
    "m/s*5": (0.2, "m/s"),
    "deg": (1.0, "deg"),
    "deg/s": (1.0, "deg/s"),
    "deg/2": (2.0, "deg"),
    "ddeg/s": (0.1, "deg/s"),
    "mrad/s": (0.18 / math.pi, "deg/s"),
    "s": (1.0, "s"),
    "ds": (0.1, "s"),
    "cs": (0.01, "s"),
    "ns": (1e-9, "s"),
    "degC": (1.0, "degC"),
    "cdegC": (0.01, "degC"),
    "mV": (0.001, "V"),
    "cV": (0.01, "V"),
    "A": (1.0, "A"),
    "cA": (0.01, "A"),
    "mA": (0.001, "A"),
    "d%": (0.1, "%"),
    "c%": (0.01, "%"),
    "Pa": (1.0, "Pa"),
    "hPa": (100.0, "Pa"),
    "kPa": (1000.0, "Pa"),
    "mbar": (100.0, "Pa"),
    "m/s/s": (1.0, "m/s/s"),
}


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """One attackable field: wire type, wire unit and the conversion to physical units."""

    name: str
    wire_type: str  # MAVLink type name, e.g. "uint16_t"
    wire_unit: str  # as the MAVLink XML writes it, e.g. "cm"
    scale: float  # physical value = wire value * scale
    unit: str  # physical unit, e.g. "m"
    lo: float  # smallest representable wire value (an int for integer types, so 64-bit ends stay exact)
    hi: float  # largest representable wire value
    integer: bool
    array: str | None = None  # an array element ("distances[3]"): the array's name ...
    index: int = -1  # ... and the element's index
    enum: str | None = None  # the MAVLink enum the XML names for this field (e.g. "MAV_CMD")

    def to_physical(self, wire: float) -> float:
        return wire * self.scale

    def to_wire(self, physical: float) -> tuple[float | int, bool]:
        """Physical value -> (wire value, clamped?). NaN becomes the range's low end, flagged as clamped."""
        raw = physical / self.scale if self.scale != 1 else physical  # 1: integers stay exact past 2**53
        if raw != raw:  # NaN: no wire type but float can carry it
            if not self.integer:
                return raw, False
            return int(self.lo), True
        if raw < self.lo:
            return (int(self.lo), True) if self.integer else (self.lo, raw < -_FLOAT32_ROUNDS_TO_MAX)
        if raw > self.hi:
            return (int(self.hi), True) if self.integer else (self.hi, raw > _FLOAT32_ROUNDS_TO_MAX)
        if self.integer:
            return round(raw), False
        return raw, False


def wire_range(wire_type: str) -> tuple[float, float, bool]:
    """(lo, hi, integer) of a MAVLink wire type; ``KeyError`` for ``char``."""
    if wire_type == "float":
        return -_FLOAT32_MAX, _FLOAT32_MAX, False
    if wire_type == "double":
        return -sys.float_info.max, sys.float_info.max, False
    lo, hi = _INT_RANGE[wire_type]
    return lo, hi, True


def _spec(name: str, wire_type: str, wire_unit: str = "") -> FieldSpec:
    scale, unit = _UNIT[wire_unit]
    lo, hi, integer = wire_range(wire_type)
    return FieldSpec(name, wire_type, wire_unit, scale, unit, lo, hi, integer)


@dataclass(frozen=True, slots=True)
class MessageSpec:
    """An attackable message: its id, its fields, and how it names a sensor and a time."""

    name: str
    msgid: int
    fields: dict[str, FieldSpec]
    default_field: str | None  # used when a rule's target names no field
    id_field: str | None  # field that carries the sensor id, if any
    time_field: str | None  # vehicle clock: "time_boot_ms" or "time_usec"
    derived: bool = False  # built from the dialect (every field), not one of the typed fifteen

    # where a typed message finds the fields its table leaves out (units.py hands it the dialect's lookup, so this
    # module imports neither: the dialect builds on these types)
    more: Callable[[str, str], FieldSpec | None] | None = None

    def field(self, name: str) -> FieldSpec | None:
        """The spec of field ``name``: the typed table's, else the dialect's (array elements as ``name[i]``)."""
        spec = self.fields.get(name)
        if spec is None and self.more is not None:
            spec = self.more(self.name, name)
        return spec

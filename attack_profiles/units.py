"""Wire <-> physical units of the MAVLink fields a profile may attack.

Profiles speak physical units (metres, m/s, degrees, seconds); pymavlink hands
the engine wire units (cm, mm, 1e7 degrees, centidegrees, ...). One table per
message says, for each attackable field, how many physical units one wire unit
is and which range the wire type can carry, so the engine can convert both ways
and clamp instead of letting pymavlink's ``struct.pack`` fail on overflow.

The fifteen typed messages below are written out rather than derived from
pymavlink at import time: importing a dialect costs more than the whole engine,
and a test checks these entries against pymavlink's own field types and units.
Every other message of the common and ardupilotmega dialects, and every field
of a typed message not in its table, is derived from the dialect on first use
(:mod:`attack_profiles.dialect`): ``MESSAGES[name]`` finds any of them, while
iterating ``MESSAGES`` lists only the typed fifteen.
"""

from __future__ import annotations

import math
import sys
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

    def field(self, name: str) -> FieldSpec | None:
        """The spec of field ``name``: the typed table's, else the dialect's (array elements as ``name[i]``)."""
        spec = self.fields.get(name)
        if spec is None and not self.derived:
            from attack_profiles import dialect  # the dialect is imported only when a profile needs it

            spec = dialect.fields(self.name).get(name)
        return spec


def _message(
    name: str,
    msgid: int,
    fields: list[tuple[str, str, str]],
    default_field: str | None = None,
    id_field: str | None = None,
    time_field: str | None = "time_boot_ms",
) -> MessageSpec:
    table = {f: _spec(f, t, u) for f, t, u in fields}
    return MessageSpec(name, msgid, table, default_field, id_field, time_field)


class _Messages(dict[str, MessageSpec]):
    """The typed messages; ``[name]`` also finds any other message of the dialect (built on first use,
    not listed, so iterating gives the typed fifteen). ``.get`` and ``in`` see the typed ones only:
    use :func:`lookup` for any message."""

    def __missing__(self, name: str) -> MessageSpec:
        from attack_profiles import dialect

        spec = dialect.message(name)
        if spec is None:
            raise KeyError(name)
        return spec


MESSAGES: dict[str, MessageSpec] = _Messages(
    (m.name, m)
    for m in (
        _message(
            "DISTANCE_SENSOR",
            132,
            [
                ("current_distance", "uint16_t", "cm"),
                ("min_distance", "uint16_t", "cm"),
                ("max_distance", "uint16_t", "cm"),
                ("covariance", "uint8_t", ""),  # cm^2 on the wire; kept raw, nothing physical to scale it to
                ("signal_quality", "uint8_t", "%"),
                ("horizontal_fov", "float", "rad"),
                ("vertical_fov", "float", "rad"),
            ],
            default_field="current_distance",
            id_field="id",
        ),
        _message(
            "LOCAL_POSITION_NED",
            32,
            [
                ("x", "float", "m"),
                ("y", "float", "m"),
                ("z", "float", "m"),
                ("vx", "float", "m/s"),
                ("vy", "float", "m/s"),
                ("vz", "float", "m/s"),
            ],
        ),
        _message(
            "GLOBAL_POSITION_INT",
            33,
            [
                ("lat", "int32_t", "degE7"),
                ("lon", "int32_t", "degE7"),
                ("alt", "int32_t", "mm"),
                ("relative_alt", "int32_t", "mm"),
                ("vx", "int16_t", "cm/s"),
                ("vy", "int16_t", "cm/s"),
                ("vz", "int16_t", "cm/s"),
                ("hdg", "uint16_t", "cdeg"),
            ],
        ),
        _message(
            "GPS_RAW_INT",
            24,
            [
                ("lat", "int32_t", "degE7"),
                ("lon", "int32_t", "degE7"),
                ("alt", "int32_t", "mm"),
                ("eph", "uint16_t", ""),  # HDOP * 100, dimensionless
                ("epv", "uint16_t", ""),
                ("vel", "uint16_t", "cm/s"),
                ("cog", "uint16_t", "cdeg"),
                ("satellites_visible", "uint8_t", ""),
                ("fix_type", "uint8_t", ""),
                ("alt_ellipsoid", "int32_t", "mm"),
                ("h_acc", "uint32_t", "mm"),
                ("v_acc", "uint32_t", "mm"),
                ("vel_acc", "uint32_t", "mm/s"),
            ],
            time_field="time_usec",
        ),
        _message(
            "ODOMETRY",
            331,
            [
                ("x", "float", "m"),
                ("y", "float", "m"),
                ("z", "float", "m"),
                ("vx", "float", "m/s"),
                ("vy", "float", "m/s"),
                ("vz", "float", "m/s"),
                ("rollspeed", "float", "rad/s"),
                ("pitchspeed", "float", "rad/s"),
                ("yawspeed", "float", "rad/s"),
                ("quality", "int8_t", "%"),
            ],
            time_field="time_usec",
        ),
        _message(
            "ATTITUDE",
            30,
            [
                ("roll", "float", "rad"),
                ("pitch", "float", "rad"),
                ("yaw", "float", "rad"),
                ("rollspeed", "float", "rad/s"),
                ("pitchspeed", "float", "rad/s"),
                ("yawspeed", "float", "rad/s"),
            ],
        ),
        _message(
            "RANGEFINDER",  # ArduPilot (ardupilotmega): its primary downward rangefinder, see quantities.py
            173,
            [("distance", "float", "m"), ("voltage", "float", "V")],
            default_field="distance",
            time_field=None,
        ),
        _message(
            "VFR_HUD",
            74,
            [("alt", "float", "m"), ("climb", "float", "m/s"), ("groundspeed", "float", "m/s")],
            time_field=None,
        ),
        _message(
            "ALTITUDE",
            141,
            [
                ("altitude_monotonic", "float", "m"),
                ("altitude_amsl", "float", "m"),
                ("altitude_local", "float", "m"),
                ("altitude_relative", "float", "m"),
                ("altitude_terrain", "float", "m"),
                ("bottom_clearance", "float", "m"),
            ],
            time_field="time_usec",
        ),
        _message(
            "GPS2_RAW",
            124,
            [
                ("lat", "int32_t", "degE7"),
                ("lon", "int32_t", "degE7"),
                ("alt", "int32_t", "mm"),
                ("fix_type", "uint8_t", ""),
                ("alt_ellipsoid", "int32_t", "mm"),
            ],
            time_field="time_usec",
        ),
        _message(
            "TERRAIN_REPORT",  # ArduPilot sends it with terrain following on (the SITL default)
            136,
            [("lat", "int32_t", "degE7"), ("lon", "int32_t", "degE7"), ("current_height", "float", "m")],
            time_field=None,
        ),
        _message(
            "AHRS2",  # ArduPilot's secondary estimator (DCM)
            178,
            [("altitude", "float", "m"), ("lat", "int32_t", "degE7"), ("lng", "int32_t", "degE7")],
            time_field=None,
        ),
        _message(
            "AHRS3",
            182,
            [("altitude", "float", "m"), ("lat", "int32_t", "degE7"), ("lng", "int32_t", "degE7")],
            time_field=None,
        ),
        _message(
            "HIGHRES_IMU",  # pressure_alt: metres from the barometer (the XML gives it no unit)
            105,
            [("pressure_alt", "float", "")],
            time_field="time_usec",
        ),
        _message(
            "SIMSTATE",  # ArduPilot SITL's own truth: a real vehicle does not send it
            164,
            [("lat", "int32_t", "degE7"), ("lng", "int32_t", "degE7")],
            time_field=None,
        ),
    )
)

MESSAGE_NAMES: tuple[str, ...] = tuple(MESSAGES)
MESSAGE_BY_ID: dict[int, MessageSpec] = {m.msgid: m for m in MESSAGES.values()}

LOCAL_POSITION_NED_ID = MESSAGES["LOCAL_POSITION_NED"].msgid

# time_usec above this is a UNIX epoch, not time since boot (about 31 years in microseconds).
EPOCH_USEC_THRESHOLD = 10**15


def lookup(message: str) -> MessageSpec | None:
    """The spec of any message of the dialect (typed or derived), or ``None``."""
    try:
        return MESSAGES[message]
    except KeyError:
        return None


def field_spec(message: str, field: str) -> FieldSpec:
    """The spec of ``message.field``; ``KeyError`` if it is not attackable."""
    spec = MESSAGES[message].field(field)
    if spec is None:
        raise KeyError(field)
    return spec

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

from attack_profiles.wire import FieldSpec, MessageSpec, _spec


def _dialect_field(message: str, name: str) -> FieldSpec | None:
    """A typed message's field that its table leaves out, from the dialect (imported only when asked)."""
    from attack_profiles import dialect

    return dialect.fields(message).get(name)


def _message(
    name: str,
    msgid: int,
    fields: list[tuple[str, str, str]],
    default_field: str | None = None,
    id_field: str | None = None,
    time_field: str | None = "time_boot_ms",
) -> MessageSpec:
    table = {f: _spec(f, t, u) for f, t, u in fields}
    return MessageSpec(name, msgid, table, default_field, id_field, time_field, more=_dialect_field)


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

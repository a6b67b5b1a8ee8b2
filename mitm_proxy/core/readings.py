"""What a live console plots: each watched sensor's reading as it came and as it left, at 10 Hz.

While a console watches (a retained ``secuav/console/<id>/online`` record says
so), each link's pipeline hands its :class:`ReadingsTap` the downlink frames of
DISTANCE_SENSOR and LOCAL_POSITION_NED: the frame as the vehicle sent it and the
frame as the ground got it (``None`` when the attack dropped it), and, when the
attack stage changed it, the value the attack made (the secure stage may have
replaced it before it left). The tap reads
the few fields it needs straight from the bytes (no decode), keeps the latest
per sensor, and the proxy publishes what changed on ``secuav/v<N>/readings``
ten times a second. With no console the pipeline has no tap and pays nothing.
"""

from __future__ import annotations

import struct
import time
from typing import Any

DISTANCE_SENSOR = 132
LOCAL_POSITION_NED = 32
_V2_MAGIC = 0xFD
_DIST = struct.Struct("<8xHxB")  # current_distance (cm) at 8, id at 11
_POS = struct.Struct("<4x3f")  # x, y, z (m) at 4, 8, 12
QUALITY_AT = 38  # DISTANCE_SENSOR.signal_quality (extension): 1 = the secure stage flags it invalid


def _payload(frame: bytes, need: int) -> bytes:
    """The payload of a frame, with the zeros MAVLink 2 truncates put back up to ``need`` bytes."""
    start = 10 if frame[0] == _V2_MAGIC else 6
    body = frame[start : start + frame[1]]
    return body if len(body) >= need else body + bytes(need - len(body))


def distance(frame: bytes) -> tuple[int, float, bool]:
    """(sensor id, distance in metres, flagged invalid) of a DISTANCE_SENSOR frame."""
    body = _payload(frame, QUALITY_AT + 1)
    cm, sensor = _DIST.unpack_from(body)
    return sensor, cm / 100.0, body[QUALITY_AT] == 1


def position(frame: bytes) -> tuple[float, float, float]:
    """(north, east, down) in metres of a LOCAL_POSITION_NED frame."""
    return _POS.unpack_from(_payload(frame, 16))


class ReadingsTap:
    """The latest original and forwarded value per sensor of one link; see the module doc."""

    ids = frozenset({DISTANCE_SENSOR, LOCAL_POSITION_NED})
    __slots__ = ("_attacked", "_attacked_position", "_position", "_sensors", "seen", "sysid")

    def __init__(self, sysid: int) -> None:
        self.sysid = sysid
        self._sensors: dict[int, dict[str, Any]] = {}
        self._position: dict[str, Any] | None = None
        self._attacked: dict[int, float] = {}  # sensor -> value after the attack stage, for the frame in flight
        self._attacked_position: tuple[Any, ...] | None = None
        self.seen = 0

    def see(self, msgid: int, original: bytes, forwarded: bytes | None) -> None:
        """One watched frame: ``forwarded`` is what left (the same object when untouched), None if dropped."""
        self.seen += 1
        if msgid == DISTANCE_SENSOR:
            sensor, orig_m, _ = distance(original)
            if forwarded is original:
                fwd_m, flagged = orig_m, False
            elif forwarded is None:
                fwd_m, flagged = None, False
            else:
                _, fwd_m, flagged = distance(forwarded)
            entry = {"original_m": orig_m, "forwarded_m": fwd_m, "flagged": flagged}
            attacked = self._attacked.pop(sensor, None)
            if attacked is not None:
                entry["attacked_m"] = attacked
            self._sensors[sensor] = entry
        else:
            orig = position(original)
            fwd = orig if forwarded is original else (None if forwarded is None else position(forwarded))
            self._position = {"original_ned_m": orig, "forwarded_ned_m": fwd}
            if self._attacked_position is not None:
                self._position["attacked_ned_m"] = self._attacked_position
                self._attacked_position = None

    def attacked(self, msgid: int, fields: dict[str, Any]) -> None:
        """The attack stage changed this frame: keep the value it made (the secure stage may replace it)."""
        if msgid == DISTANCE_SENSOR:
            sensor, cm = fields.get("id"), fields.get("current_distance")
            if isinstance(sensor, int) and isinstance(cm, int | float):
                self._attacked[sensor] = cm / 100.0
        elif msgid == LOCAL_POSITION_NED:
            self._attacked_position = (fields.get("x"), fields.get("y"), fields.get("z"))

    def take(self) -> dict[str, Any] | None:
        """What changed since the last call, as the ``readings`` payload; None when nothing did."""
        if not self._sensors and self._position is None:
            return None
        out: dict[str, Any] = {"sysid": self.sysid, "t": time.time(),
                               "sensors": {str(k): v for k, v in sorted(self._sensors.items())}}  # fmt: skip
        if self._position is not None:
            out["position"] = self._position
        self._sensors = {}
        self._position = None
        return out

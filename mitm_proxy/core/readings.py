"""What a live console plots: each watched sensor's reading as it came and as it left, at 10 Hz.

While a console watches (a retained ``secuav/console/<id>/online`` record says
so), a :class:`ReadingsTap` observes each link's pipeline (its four hooks,
:class:`mitm_proxy.core.pipeline.Observer`) and keeps, of the downlink frames of
DISTANCE_SENSOR and LOCAL_POSITION_NED, the frame as the vehicle sent it and the
frame as the ground got it (``None`` when the attack dropped it), and, when the
stage it is told to watch (``after``, the attack stage) changed it, the value that
stage made (the secure stage may have replaced it before it left). The tap reads
the few fields it needs straight from the bytes (no decode), keeps the latest
per sensor, and the proxy publishes what changed on ``secuav/v<N>/readings``
ten times a second. With no console the pipeline has no tap and pays nothing.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from mavframe.layout import DISTANCE_SENSOR, LOCAL_POSITION_NED, offset, payload
from mavframe.packet import Direction, Header, Packet
from secuav_common.sensor_ids import QUALITY_INVALID

_DIST_AT = offset(DISTANCE_SENSOR, "current_distance")  # uint16 cm
_ID_AT = offset(DISTANCE_SENSOR, "id")  # uint8
QUALITY_AT = offset(DISTANCE_SENSOR, "signal_quality")  # 1 = the secure stage flags it invalid
_POS_AT = offset(LOCAL_POSITION_NED, "x")  # x, y, z (float32 m), in a row
if TYPE_CHECKING:
    from mitm_proxy.core.pipeline import Stage

_CM = struct.Struct("<H")
_XYZ = struct.Struct("<3f")
_DIST_NEED = max(_DIST_AT + _CM.size, _ID_AT + 1, QUALITY_AT + 1)


def distance(frame: bytes) -> tuple[int, float, bool]:
    """(sensor id, distance in metres, flagged invalid) of a DISTANCE_SENSOR frame."""
    body = payload(frame, _DIST_NEED)
    (cm,) = _CM.unpack_from(body, _DIST_AT)
    return body[_ID_AT], cm / 100.0, body[QUALITY_AT] == QUALITY_INVALID


def position(frame: bytes) -> tuple[float, float, float]:
    """(north, east, down) in metres of a LOCAL_POSITION_NED frame."""
    north, east, down = _XYZ.unpack_from(payload(frame, _POS_AT + _XYZ.size), _POS_AT)
    return north, east, down


class ReadingsTap:
    """The latest original and forwarded value per sensor of one link; see the module doc."""

    ids = frozenset({DISTANCE_SENSOR, LOCAL_POSITION_NED})
    __slots__ = ("_attacked", "_attacked_position", "_position", "_sensors", "after", "seen", "sysid")

    def __init__(self, sysid: int, after: str = "attack") -> None:
        self.sysid = sysid
        self.after = after  # the stage whose changes count as "attacked"
        self._sensors: dict[int, dict[str, Any]] = {}
        self._position: dict[str, Any] | None = None
        self._attacked: dict[int, float] = {}  # sensor -> value after the attack stage, for the frame in flight
        self._attacked_position: tuple[Any, ...] | None = None
        self.seen = 0

    # -- the pipeline's observer hooks (mitm_proxy.core.pipeline.Observer) ---------------------------------

    def frames_in(self, direction: Direction, frames: Sequence[tuple[Header, bytes]]) -> None:
        pass

    def after_stage(self, stage: Stage, pkts: Sequence[Packet]) -> None:
        if stage.name != self.after:
            return
        for p in pkts:
            if p.changed and p.fields is not None and p.direction is Direction.DOWNLINK and p.header.msgid in self.ids:
                self.attacked(p.header.msgid, p.fields)

    def frame_out(self, direction: Direction, pos: int, header: Header, raw: bytes, data: bytes,
                  pkt: Packet | None, delay_s: float) -> None:  # fmt: skip
        if direction is Direction.DOWNLINK and header.msgid in self.ids and (pkt is None or not pkt.injected):
            self.see(header.msgid, raw, raw if pkt is None or not pkt.changed else data)

    def dropped(self, direction: Direction, pos: int, header: Header, raw: bytes, pkt: Packet) -> None:
        if direction is Direction.DOWNLINK and header.msgid in self.ids:
            self.see(header.msgid, raw, None)

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

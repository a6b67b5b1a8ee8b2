"""The MAVLink parameter protocol over the vehicle's PX4 parameter table.

Integers travel "bytewise" as PX4 sends them (the int32's bytes in the float
field, MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE), which MAVSDK and
QGroundControl expect from a PX4 autopilot. PARAM_REQUEST_LIST is answered
by streaming the whole table over the next ticks, each PARAM_VALUE with the
table size and its index, so a GCS can tell when it has everything and
re-request any index it missed.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import Param, VehicleModel

Message = mavlink.MAVLink_message
PARAMS_PER_TICK = 25  # a burst small enough for any GCS's socket buffer; the full list takes a few ticks


def int_to_wire(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def wire_to_int(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def param_id(raw: str | bytes) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else raw
    return text.split("\0", 1)[0]


class ParamServer:
    def __init__(
        self,
        vehicle: VehicleModel,
        mav: mavlink.MAVLink,
        send: Callable[[Message], None],
        say: Callable[[int, str], None],
    ) -> None:
        self.v = vehicle
        self.mav = mav
        self.send = send
        self.say = say
        self._queue: deque[int] = deque()

    def _table(self) -> list[Param]:
        return self.v.params()

    def _value_msg(self, p: Param, index: int, count: int) -> Message:
        if p.is_int:
            value, ptype = int_to_wire(int(p.value)), mavlink.MAV_PARAM_TYPE_INT32
        else:
            value, ptype = p.value, mavlink.MAV_PARAM_TYPE_REAL32
        return self.mav.param_value_encode(p.name.encode("ascii"), value, ptype, count, index)

    def handle(self, msg: Message) -> None:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            # A second request restarts the stream rather than doubling it.
            self._queue = deque(range(len(self._table())))
        elif kind == "PARAM_REQUEST_READ":
            self._read(msg)
        elif kind == "PARAM_SET":
            self._set(msg)

    def pump(self) -> None:
        """Send the next slice of a requested list (called every tick)."""
        if not self._queue:
            return
        table = self._table()
        for _ in range(min(PARAMS_PER_TICK, len(self._queue))):
            i = self._queue.popleft()
            if i < len(table):
                self.send(self._value_msg(table[i], i, len(table)))

    @property
    def streaming(self) -> bool:
        return bool(self._queue)

    def _read(self, msg: Message) -> None:
        table = self._table()
        if msg.param_index >= 0:
            if msg.param_index >= len(table):
                self.say(mavlink.MAV_SEVERITY_WARNING, f"Parameter index {msg.param_index} does not exist")
                return
            self.send(self._value_msg(table[msg.param_index], msg.param_index, len(table)))
            return
        name = param_id(msg.param_id)
        for i, p in enumerate(table):
            if p.name == name:
                self.send(self._value_msg(p, i, len(table)))
                return
        self.say(mavlink.MAV_SEVERITY_WARNING, f"Parameter {name} does not exist")

    def _set(self, msg: Message) -> None:
        name = param_id(msg.param_id)
        current = self.v.get_param(name)
        if current is None:
            self.say(mavlink.MAV_SEVERITY_WARNING, f"Parameter {name} does not exist")
            return
        value = float(msg.param_value)
        if current.is_int:
            # Bytewise (PX4, MAVSDK, QGC) first; a C-cast integer (some scripts) second.
            result = self.v.set_param(name, float(wire_to_int(value)))
            if result is None and math.isfinite(value) and value == int(value):
                result = self.v.set_param(name, value)
        else:
            result = self.v.set_param(name, value)
        if result is None:
            shown = wire_to_int(value) if current.is_int else value
            self.say(mavlink.MAV_SEVERITY_WARNING, f"Parameter {name}: value {shown} rejected")
            result = current  # PX4 answers a refused set with the unchanged value
        table = self._table()
        index = next((i for i, p in enumerate(table) if p.name == name), 0)
        self.send(self._value_msg(result, index, len(table)))

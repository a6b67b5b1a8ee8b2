"""Which telemetry messages go out how often, PX4 style.

Defaults follow PX4's ``mavlink_main.cpp`` stream lists, trimmed to what the
bench's clients read and to rates that keep sixteen vehicles within one core.
SET_MESSAGE_INTERVAL (MAVSDK ``set_rate_*``) changes them per message id:
interval 0 restores the default, -1 stops the stream. Time is sim time, so a
run at ``--speed 10`` sends ten times as many messages per wall second, each
with the same sim-time spacing.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

# message id -> default rate (Hz); a rate of 0 means "only on request"
DEFAULT_RATES_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 20.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_ALTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: 0.0,
}
# Sent as the sensors produce them (interval 0); an interval set by a GCS throttles each sensor id.
EVENT_STREAMS = {mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR}
MIN_INTERVAL_S = 0.001  # 1 kHz; faster requests are clamped as PX4 does


class StreamTable:
    """Per-message intervals and the sim time each stream is next due."""

    def __init__(self) -> None:
        self._interval_s: dict[int, float] = {}
        self._next_t_s: dict[int, float] = {}
        self.event_interval_s: dict[int, float] = {}
        for msg_id, rate in DEFAULT_RATES_HZ.items():
            self._apply(msg_id, 1.0 / rate if rate > 0 else math.inf)

    def _apply(self, msg_id: int, interval_s: float) -> None:
        self._interval_s[msg_id] = interval_s
        self._next_t_s[msg_id] = 0.0 if math.isfinite(interval_s) else math.inf

    def supports(self, msg_id: int) -> bool:
        return msg_id in DEFAULT_RATES_HZ or msg_id in EVENT_STREAMS

    def set_interval(self, msg_id: int, interval_us: float, now_s: float) -> str | None:
        """Apply SET_MESSAGE_INTERVAL; returns why not, or None on success."""
        if not self.supports(msg_id):
            return f"message {msg_id} is not streamed by this vehicle"
        if not math.isfinite(interval_us):
            return f"interval {interval_us!r} is not a number"
        if msg_id in EVENT_STREAMS:
            if interval_us == 0:
                self.event_interval_s.pop(msg_id, None)
            else:
                self.event_interval_s[msg_id] = math.inf if interval_us < 0 else max(MIN_INTERVAL_S, interval_us / 1e6)
            return None
        if interval_us == 0:
            rate = DEFAULT_RATES_HZ[msg_id]
            interval_s = 1.0 / rate if rate > 0 else math.inf
        elif interval_us < 0:
            interval_s = math.inf
        else:
            interval_s = max(MIN_INTERVAL_S, interval_us / 1e6)
        self._interval_s[msg_id] = interval_s
        self._next_t_s[msg_id] = now_s if math.isfinite(interval_s) else math.inf
        return None

    def interval_us(self, msg_id: int) -> int:
        """MESSAGE_INTERVAL.interval_us as MAVLink defines it (-1 disabled, 0 not available)."""
        if msg_id in EVENT_STREAMS:
            iv = self.event_interval_s.get(msg_id, 0.0)
        else:
            iv = self._interval_s.get(msg_id, math.inf)
        if math.isinf(iv):
            return -1 if self.supports(msg_id) else 0
        return round(iv * 1e6)

    def due(self, now_s: float) -> list[int]:
        """Message ids to send at ``now_s``; each stream is rescheduled on its own grid."""
        out = []
        for msg_id, next_t in self._next_t_s.items():
            if now_s + 1e-9 >= next_t:
                out.append(msg_id)
                iv = self._interval_s[msg_id]
                # Stay on the grid, but never try to catch up a backlog (after a long pause).
                nxt = next_t + iv
                self._next_t_s[msg_id] = nxt if nxt > now_s else now_s + iv
        return out

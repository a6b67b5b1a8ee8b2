"""COMMAND_LONG / COMMAND_INT -> vehicle actions, each answered by one COMMAND_ACK.

Every command gets an answer within the same tick: MAVSDK retries and then
fails on silence. Refusals carry the reason as STATUSTEXT, PX4 style;
commands the bench does not implement get MAV_RESULT_UNSUPPORTED.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import FlightMode, Outcome, Repositionable, Result, SpeedSettable
from flightsim.mavlink import modes
from secuav_common.geo import geodetic_to_ned

if TYPE_CHECKING:
    from flightsim.mavlink.personality import Px4Personality

MAX_MSG_ID = 0xFFFF  # MESSAGE_INTERVAL.message_id is a uint16
FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: arm/disarm regardless of checks
_GLOBAL_INT_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
}
_RELATIVE_FRAMES = {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}


@dataclass(frozen=True, slots=True)
class Command:
    """COMMAND_LONG and COMMAND_INT in one shape (lat/lon in degrees for global frames)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    relative_alt: bool = False  # param7 is above home rather than AMSL (COMMAND_INT relative frames)

    @classmethod
    def from_message(cls, msg: mavlink.MAVLink_message) -> Command:
        if msg.get_type() == "COMMAND_LONG":
            return cls(
                msg.command, (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
            )
        scale = 1e7 if msg.frame in _GLOBAL_INT_FRAMES else 1e4
        x = math.nan if msg.x == 0x7FFFFFFF else msg.x / scale  # INT32_MAX: "not set"
        y = math.nan if msg.y == 0x7FFFFFFF else msg.y / scale
        return cls(
            msg.command,
            (msg.param1, msg.param2, msg.param3, msg.param4, x, y, msg.z),
            relative_alt=msg.frame in _RELATIVE_FRAMES,
        )


Handler = Callable[["Px4Personality", Command], Outcome]
_ACCEPTED = Outcome(Result.ACCEPTED)


def _whole(value: float) -> int:
    """A command parameter as an integer; NaN/inf (unused) become 0."""
    return round(value) if math.isfinite(value) else 0


def _arm_disarm(p: Px4Personality, c: Command) -> Outcome:
    # MAVSDK leaves unused params NaN; a float comparison is false for NaN.
    force = c.params[1] == FORCE_MAGIC
    if c.params[0] >= 0.5:
        return p.vehicle.arm()
    return p.vehicle.disarm(force=force)


def _altitude_above_home(p: Px4Personality, c: Command) -> float | None:
    alt = c.params[6]
    if not math.isfinite(alt):
        return None
    return alt if c.relative_alt else alt - p.vehicle.home.alt_m


def _takeoff(p: Px4Personality, c: Command) -> Outcome:
    # PX4: param7 is the takeoff altitude AMSL; NaN (MAVSDK's default) means MIS_TAKEOFF_ALT.
    return p.vehicle.takeoff(_altitude_above_home(p, c))


def _land(p: Px4Personality, c: Command) -> Outcome:
    return p.vehicle.land()


def _rtl(p: Px4Personality, c: Command) -> Outcome:
    return p.vehicle.return_to_launch()


def _set_mode(p: Px4Personality, c: Command) -> Outcome:
    base = _whole(c.params[0])
    if not base & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return Outcome(Result.DENIED, "Mode change denied: only PX4 custom modes are supported")
    mode = modes.decode(_whole(c.params[1]), _whole(c.params[2]))
    if not isinstance(mode, FlightMode):  # FlightMode is a StrEnum: test for it, not for str
        return Outcome(Result.DENIED, f"Mode change denied: {mode}")
    return p.vehicle.set_mode(mode)


def _reposition(p: Px4Personality, c: Command) -> Outcome:
    v = p.vehicle
    if not isinstance(v, Repositionable):
        return Outcome(Result.UNSUPPORTED, "Reposition not supported by this vehicle model")
    est = v.estimate.pos_ned_m
    lat, lon = c.params[4], c.params[5]
    alt = _altitude_above_home(p, c)
    north, east = est[0], est[1]
    if math.isfinite(lat) and math.isfinite(lon):
        north, east, _ = geodetic_to_ned(v.home, lat, lon, v.home.alt_m)
    down = -alt if alt is not None else est[2]
    yaw = math.radians(c.params[3]) if math.isfinite(c.params[3]) else None
    return v.reposition((north, east, down), yaw)


def _change_speed(p: Px4Personality, c: Command) -> Outcome:
    # param2: speed in m/s; -1 "no change", -2 "back to the default" (MAV_CMD_DO_CHANGE_SPEED)
    v = p.vehicle
    if not isinstance(v, SpeedSettable):
        return Outcome(Result.UNSUPPORTED, "Change speed not supported by this vehicle model")
    speed = c.params[1]
    if speed == -1:
        return _ACCEPTED
    return v.set_cruise_speed(None if speed == -2 else speed)


def _mission_start(p: Px4Personality, c: Command) -> Outcome:
    first = c.params[0]
    if math.isfinite(first) and first > 0:
        reason = p.missions.set_current(round(first))
        if reason:
            return Outcome(Result.DENIED, reason)
    return p.vehicle.set_mode(FlightMode.MISSION)


def _set_mission_current(p: Px4Personality, c: Command) -> Outcome:
    reason = p.missions.set_current(_whole(c.params[0]))
    return Outcome(Result.DENIED, reason) if reason else _ACCEPTED


def _set_message_interval(p: Px4Personality, c: Command) -> Outcome:
    msg_id = round(c.params[0]) if math.isfinite(c.params[0]) else -1
    reason = p.streams.set_interval(msg_id, c.params[1], p.now_s)
    return Outcome(Result.DENIED, f"Set message interval denied: {reason}") if reason else _ACCEPTED


def _get_message_interval(p: Px4Personality, c: Command) -> Outcome:
    msg_id = round(c.params[0]) if math.isfinite(c.params[0]) else -1
    if not 0 <= msg_id <= MAX_MSG_ID:
        return Outcome(Result.DENIED, f"Get message interval denied: no message id {msg_id}")
    p.send(p.encoder.mav.message_interval_encode(msg_id, p.streams.interval_us(msg_id)))
    return _ACCEPTED


def _request_message(p: Px4Personality, c: Command) -> Outcome:
    msg_id = round(c.params[0]) if math.isfinite(c.params[0]) else -1
    if not p.request_message(msg_id, c.params[1]):
        return Outcome(Result.DENIED, f"Request denied: message {msg_id} not available")
    return _ACCEPTED


def _autopilot_capabilities(p: Px4Personality, c: Command) -> Outcome:
    p.request_message(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0.0)
    return _ACCEPTED


def _home_position(p: Px4Personality, c: Command) -> Outcome:
    p.request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0.0)
    return _ACCEPTED


HANDLERS: dict[int, Handler] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: _arm_disarm,
    mavlink.MAV_CMD_NAV_TAKEOFF: _takeoff,
    mavlink.MAV_CMD_NAV_LAND: _land,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: _rtl,
    mavlink.MAV_CMD_DO_SET_MODE: _set_mode,
    mavlink.MAV_CMD_DO_REPOSITION: _reposition,
    mavlink.MAV_CMD_DO_CHANGE_SPEED: _change_speed,
    mavlink.MAV_CMD_MISSION_START: _mission_start,
    mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: _set_mission_current,
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: _set_message_interval,
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: _get_message_interval,
    mavlink.MAV_CMD_REQUEST_MESSAGE: _request_message,
    mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _autopilot_capabilities,
    mavlink.MAV_CMD_GET_HOME_POSITION: _home_position,
}


def dispatch(p: Px4Personality, c: Command) -> Outcome:
    handler = HANDLERS.get(c.command)
    if handler is None:
        return Outcome(Result.UNSUPPORTED, f"Command {c.command} not supported")
    return handler(p, c)

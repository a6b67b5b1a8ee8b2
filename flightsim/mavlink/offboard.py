"""SET_POSITION_TARGET_* -> api.OffboardSetpoint, following PX4's reading of the type mask.

A set bit in ``type_mask`` means "ignore this field". A group (position,
velocity, acceleration) is used only when none of its three bits is set;
yaw and yaw rate each have their own bit. MAVSDK's masks: position+yaw 2552,
velocity NED+yaw 2503, position+velocity 2496, velocity body+yaw rate 1479,
acceleration 3135.
"""

from __future__ import annotations

import math
from typing import Literal

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import OffboardSetpoint, Vec3
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import Home

POS_IGNORE = 0b111
VEL_IGNORE = 0b111 << 3
ACC_IGNORE = 0b111 << 6
FORCE = 1 << 9
YAW_IGNORE = 1 << 10
YAW_RATE_IGNORE = 1 << 11

NED_FRAMES = {mavlink.MAV_FRAME_LOCAL_NED}
BODY_FRAMES = {mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_FRD, mavlink.MAV_FRAME_BODY_OFFSET_NED}
GLOBAL_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL: "amsl",
    mavlink.MAV_FRAME_GLOBAL_INT: "amsl",
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: "relative",
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: "relative",
}


def _group(mask: int, ignore: int, values: tuple[float, float, float]) -> tuple[float, float, float] | None:
    if mask & ignore:
        return None
    return values if all(math.isfinite(v) for v in values) else None


def _yaw(mask: int, yaw: float, yaw_rate: float) -> tuple[float | None, float | None]:
    yaw_sp = None if mask & YAW_IGNORE or not math.isfinite(yaw) else yaw
    rate_sp = None if mask & YAW_RATE_IGNORE or not math.isfinite(yaw_rate) else yaw_rate
    return yaw_sp, rate_sp


def _empty(sp: OffboardSetpoint) -> bool:
    return sp.pos_ned_m is None and sp.vel_m_s is None and sp.acc_m_s2 is None


def decode_local(msg: mavlink.MAVLink_set_position_target_local_ned_message) -> OffboardSetpoint | str:
    """The setpoint, or why it was rejected."""
    mask, frame = msg.type_mask, msg.coordinate_frame
    kind: Literal["ned", "body"]
    if frame in NED_FRAMES:
        kind = "ned"
    elif frame in BODY_FRAMES:
        kind = "body"
    else:
        return f"offboard: coordinate frame {frame} not supported (LOCAL_NED or BODY_NED)"
    pos = _group(mask, POS_IGNORE, (msg.x, msg.y, msg.z))
    if pos is not None and kind == "body":
        return "offboard: positions in a body frame are not supported"
    return _setpoint(msg, pos, kind)


def decode_global(msg: mavlink.MAVLink_set_position_target_global_int_message, home: Home) -> OffboardSetpoint | str:
    """SET_POSITION_TARGET_GLOBAL_INT (MAVSDK ``set_position_global``) in the local frame."""
    mask, frame = msg.type_mask, msg.coordinate_frame
    alt_kind = GLOBAL_FRAMES.get(frame)
    if alt_kind is None:
        return f"offboard: coordinate frame {frame} not supported for global setpoints"
    pos = None
    if not mask & POS_IGNORE:
        alt_amsl = msg.alt if alt_kind == "amsl" else home.alt_m + msg.alt
        pos = geodetic_to_ned(home, msg.lat_int / 1e7, msg.lon_int / 1e7, alt_amsl)
    return _setpoint(msg, pos, "ned")


def _setpoint(
    msg: mavlink.MAVLink_set_position_target_local_ned_message | mavlink.MAVLink_set_position_target_global_int_message,
    pos: Vec3 | None,
    frame: Literal["ned", "body"],
) -> OffboardSetpoint | str:
    """The velocity, acceleration and yaw parts both setpoint messages share, around an already-decoded position."""
    mask = msg.type_mask
    yaw, yaw_rate = _yaw(mask, msg.yaw, msg.yaw_rate)
    sp = OffboardSetpoint(
        pos_ned_m=pos,
        vel_m_s=_group(mask, VEL_IGNORE, (msg.vx, msg.vy, msg.vz)),
        acc_m_s2=_group(mask, ACC_IGNORE, (msg.afx, msg.afy, msg.afz)),
        yaw_rad=yaw,
        yaw_rate_rad_s=yaw_rate,
        frame=frame,
    )
    if _empty(sp):
        return f"offboard: type mask {mask} leaves nothing to fly"
    return sp

"""DISTANCE_SENSOR, VISION_POSITION_ESTIMATE and ODOMETRY arriving from a companion -> api readings.

What a real autopilot does with them: PX4 takes a MAVLink distance sensor and external vision
(``EKF2_EV_CTRL``), ArduPilot a MAVLink rangefinder (``RNGFNDx_TYPE 10``) and external navigation
(``EK3_SRC1_POSXY 6``). Which of them the vehicle expects, and from which component, is the scenario's
``external`` block; :class:`flightsim.api.ExternalInput` decides, this module only decodes.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import ExternalPosition, ExternalRange

Message = mavlink.MAVLink_message
MESSAGES = frozenset({"DISTANCE_SENSOR", "VISION_POSITION_ESTIMATE", "ODOMETRY"})
# ODOMETRY frames whose x, y, z are the local NED position (FRD shares its origin and axes on a level map).
ODOMETRY_FRAMES = frozenset({mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD})


def decode(msg: Message) -> ExternalRange | ExternalPosition | None:
    """The reading a message carries; None when it cannot be one (ODOMETRY in a frame we do not read)."""
    src = msg.get_srcSystem(), msg.get_srcComponent()
    kind = msg.get_type()
    if kind == "DISTANCE_SENSOR":
        # current_distance in cm; PX4's drivers send max_distance + 1 cm (or more) for "no target".
        cm = msg.current_distance
        distance = math.nan if cm > msg.max_distance > 0 else cm / 100.0
        return ExternalRange(*src, msg.id, distance, msg.orientation)
    if kind == "VISION_POSITION_ESTIMATE":
        return ExternalPosition(*src, (msg.x, msg.y, msg.z), "vision_position_estimate")
    if kind == "ODOMETRY":
        if msg.frame_id not in ODOMETRY_FRAMES:
            return None
        return ExternalPosition(*src, (msg.x, msg.y, msg.z), "odometry")
    return None

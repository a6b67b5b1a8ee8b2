"""The autopilot's control loops, PX4-style cascade: position -> velocity -> attitude -> rate -> mixer."""

from flightsim.control.attitude import AttitudeController, AttitudeGains
from flightsim.control.mixer import MotorModel, XQuadMixer
from flightsim.control.position import AttitudeTarget, Limits, PositionController, PositionGains, Setpoint
from flightsim.control.rate import RateController, RateGains

__all__ = [
    "AttitudeController",
    "AttitudeGains",
    "AttitudeTarget",
    "Limits",
    "MotorModel",
    "PositionController",
    "PositionGains",
    "RateController",
    "RateGains",
    "Setpoint",
    "XQuadMixer",
]

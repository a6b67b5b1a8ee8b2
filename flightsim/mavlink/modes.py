"""PX4 flight modes on the wire: HEARTBEAT.custom_mode and DO_SET_MODE.

PX4 packs its mode as ``main_mode << 16 | sub_mode << 24``
(``px4_custom_mode.h``); QGroundControl, MAVProxy and MAVSDK decode it so.
"""

from __future__ import annotations

from flightsim.api import FlightMode

# PX4 main modes
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = 1, 2, 3, 4, 5, 6, 7
# PX4 AUTO sub modes
SUB_READY, SUB_TAKEOFF, SUB_LOITER, SUB_MISSION, SUB_RTL, SUB_LAND = 1, 2, 3, 4, 5, 6

_TO_WIRE: dict[FlightMode, tuple[int, int]] = {
    FlightMode.MANUAL: (MAIN_MANUAL, 0),
    FlightMode.POSITION: (MAIN_POSCTL, 0),
    FlightMode.HOLD: (MAIN_AUTO, SUB_LOITER),
    FlightMode.TAKEOFF: (MAIN_AUTO, SUB_TAKEOFF),
    FlightMode.LAND: (MAIN_AUTO, SUB_LAND),
    FlightMode.RTL: (MAIN_AUTO, SUB_RTL),
    FlightMode.MISSION: (MAIN_AUTO, SUB_MISSION),
    FlightMode.OFFBOARD: (MAIN_OFFBOARD, 0),
}
_AUTO_SUBS = {sub: mode for mode, (main, sub) in _TO_WIRE.items() if main == MAIN_AUTO}
_MAIN_NAMES = {MAIN_ALTCTL: "Altitude", MAIN_ACRO: "Acro", MAIN_STABILIZED: "Stabilized"}


def main_sub(mode: FlightMode) -> tuple[int, int]:
    """PX4's (main mode, sub mode) of ``mode``: MAV_CMD_DO_SET_MODE's param2 and param3."""
    return _TO_WIRE[mode]


def custom_mode(mode: FlightMode) -> int:
    """HEARTBEAT.custom_mode of ``mode`` (e.g. Hold -> 50593792)."""
    main, sub = main_sub(mode)
    return (main << 16) | (sub << 24)


def decode(main_mode: int, sub_mode: int) -> FlightMode | str:
    """The FlightMode a GCS asks for, or a reason why the bench cannot fly it."""
    if main_mode == MAIN_AUTO:
        # AUTO with no sub mode (or READY) is what QGC sends for "Mission".
        if sub_mode in (0, SUB_READY):
            return FlightMode.MISSION
        return _AUTO_SUBS.get(sub_mode, f"auto sub mode {sub_mode} not supported")
    for mode, (main, _sub) in _TO_WIRE.items():
        if main == main_mode and main != MAIN_AUTO:
            return mode
    name = _MAIN_NAMES.get(main_mode, f"main mode {main_mode}")
    return f"{name} mode not supported (no manual control on this vehicle)"


def decode_custom_mode(value: int) -> FlightMode | str:
    """Decode SET_MODE.custom_mode (the same packing as HEARTBEAT)."""
    return decode((value >> 16) & 0xFF, (value >> 24) & 0xFF)

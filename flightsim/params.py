"""PX4 parameters: the ones this autopilot uses plus the common ones GCSs read.

Names, types and defaults follow PX4 (v1.14) so QGroundControl, MAVProxy and
MAVSDK find what they look for. A few defaults differ where the bench's small
indoor-sized scenarios need it (marked "bench:"). ``set`` validates the type
and range and refuses unknown names, as PX4 does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from flightsim.api import Param


@dataclass(frozen=True, slots=True)
class ParamSpec:
    name: str
    default: float
    is_int: bool = False
    min: float = -math.inf
    max: float = math.inf
    used: bool = False  # the simulated autopilot reads it (others are for GCS compatibility)


def _f(name: str, default: float, lo: float = -math.inf, hi: float = math.inf, used: bool = False) -> ParamSpec:
    return ParamSpec(name, default, False, lo, hi, used)


def _i(name: str, default: int, lo: float = -(2**31), hi: float = 2**31 - 1, used: bool = False) -> ParamSpec:
    return ParamSpec(name, float(default), True, lo, hi, used)


SPECS: tuple[ParamSpec, ...] = (
    # Used by the commander, navigator and controllers.
    _f("MIS_TAKEOFF_ALT", 2.5, 0.0, 80.0, used=True),
    _f("MPC_XY_VEL_MAX", 12.0, 0.0, 20.0, used=True),
    _f("MPC_XY_CRUISE", 5.0, 0.0, 20.0, used=True),
    _f("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, used=True),
    _f("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, used=True),
    _f("MPC_TKO_SPEED", 1.5, 1.0, 5.0, used=True),
    _f("MPC_LAND_SPEED", 0.7, 0.6, 4.0, used=True),
    _f("MPC_LAND_ALT2", 2.0, 0.0, 122.0, used=True),  # bench: PX4 uses 5 m
    _f("MPC_ACC_HOR", 3.0, 2.0, 15.0, used=True),
    _f("MPC_ACC_UP_MAX", 4.0, 2.0, 15.0, used=True),
    _f("MPC_ACC_DOWN_MAX", 3.0, 2.0, 15.0, used=True),
    _f("MPC_TILTMAX_AIR", 35.0, 20.0, 89.0, used=True),  # bench: PX4 uses 45 deg
    _f("MPC_XY_P", 1.2, 0.0, 2.0, used=True),  # bench: tuned for the JSBSim F450 (PX4 0.95)
    _f("MPC_Z_P", 1.0, 0.0, 1.5, used=True),
    _f("MPC_XY_VEL_P_ACC", 4.0, 1.2, 5.0, used=True),  # bench: tuned (PX4 1.8)
    _f("MPC_XY_VEL_I_ACC", 0.4, 0.0, 60.0, used=True),
    _f("MPC_XY_VEL_D_ACC", 0.2, 0.0, 2.0, used=True),
    _f("MPC_Z_VEL_P_ACC", 4.0, 2.0, 15.0, used=True),
    _f("MPC_Z_VEL_I_ACC", 2.0, 0.2, 3.0, used=True),
    _i("MPC_YAW_MODE", 0, 0, 4, used=True),  # 0: face the next waypoint on auto legs
    _f("NAV_ACC_RAD", 0.5, 0.05, 200.0, used=True),  # bench: PX4 uses 10 m
    _f("NAV_MC_ALT_RAD", 0.3, 0.05, 200.0, used=True),  # bench: PX4 uses 0.8 m
    _f("RTL_RETURN_ALT", 5.0, 0.0, 150.0, used=True),  # bench: PX4 uses 60 m
    _f("COM_OF_LOSS_T", 1.0, 0.0, 60.0, used=True),
    _i("COM_OBL_RC_ACT", 0, 0, 7),
    _f("COM_DISARM_LAND", 2.0, -1.0, 20.0, used=True),
    _f("COM_DISARM_PRFLT", 10.0, -1.0, 20.0, used=True),
    _f("LNDMC_Z_VEL_MAX", 0.5, 0.1, 10.0, used=True),
    _f("COM_LOW_BAT_ACT", 0.0, 0.0, 3.0),
    _f("BAT_LOW_THR", 0.15, 0.12, 0.5, used=True),
    _f("BAT_CRIT_THR", 0.07, 0.05, 0.5),
    _i("BAT1_N_CELLS", 4, 1, 16, used=True),
    _f("BAT1_CAPACITY", 5000.0, -1.0, 100000.0, used=True),
    # Identity and links that QGroundControl and MAVSDK read.
    _i("SYS_AUTOSTART", 4001, 0, 9999999),  # 4001: generic quadcopter X
    _i("SYS_AUTOCONFIG", 0, 0, 2),
    _i("SYS_HITL", 0, -1, 2),
    _i("MAV_SYS_ID", 1, 1, 250),
    _i("MAV_COMP_ID", 1, 1, 250),
    _i("MAV_TYPE", 2, 0, 22),
    _i("MAV_PROTO_VER", 2, 0, 2),
    _i("CBRK_SUPPLY_CHK", 894281, 0, 894281),
    _i("CBRK_USB_CHK", 197848, 0, 197848),
    _i("COM_RC_IN_MODE", 4, 0, 4),  # 4: stick input disabled, no RC needed
    _f("COM_RC_LOSS_T", 0.5, 0.0, 35.0),
    _i("NAV_RCL_ACT", 2, 0, 6),
    _i("NAV_DLL_ACT", 0, 0, 6),
    _i("COM_ARM_WO_GPS", 1, 0, 1),
    _i("COM_PREARM_MODE", 0, 0, 2),
    _i("GF_ACTION", 1, 0, 5),
    _f("GF_MAX_HOR_DIST", 0.0, 0.0, 10000.0),
    _f("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0),
    _f("MC_ROLL_P", 6.5, 0.0, 12.0),
    _f("MC_PITCH_P", 6.5, 0.0, 12.0),
    _f("MC_YAW_P", 2.8, 0.0, 5.0),
    _f("MC_ROLLRATE_MAX", 220.0, 0.0, 1800.0),
    _f("MC_PITCHRATE_MAX", 220.0, 0.0, 1800.0),
    _f("MC_YAWRATE_MAX", 200.0, 0.0, 1800.0),
    _f("MPC_THR_HOVER", 0.5, 0.1, 0.8),
    _f("MPC_HOLD_MAX_XY", 0.8, 0.0, 3.0),
    _i("EKF2_AID_MASK", 1, 0, 1023),
    _i("EKF2_HGT_REF", 1, 0, 3),
    _i("SENS_EN_SF1XX", 0, 0, 6),
    _f("RTL_DESCEND_ALT", 30.0, 2.0, 100.0),
    _f("RTL_LAND_DELAY", 0.0, -1.0, 300.0),
    _i("MIS_DIST_1WP", 900, 0, 10000),
)

_BY_NAME = {s.name: s for s in SPECS}
assert all(len(s.name) <= 16 for s in SPECS), "MAVLink param ids hold at most 16 characters"


class Params:
    """The vehicle's parameter table, in PX4's order (alphabetical, as PX4 lists them)."""

    def __init__(self, sysid: int = 1) -> None:
        self._values = {s.name: s.default for s in SPECS}
        self._values["MAV_SYS_ID"] = float(sysid)
        self._order = sorted(self._values)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def names(self) -> list[str]:
        return list(self._order)

    def get(self, name: str) -> Param | None:
        spec = _BY_NAME.get(name)
        if spec is None:
            return None
        return Param(name, self._values[name], spec.is_int)

    def all(self) -> list[Param]:
        return [Param(n, self._values[n], _BY_NAME[n].is_int) for n in self._order]

    def validate(self, name: str, value: float) -> str | None:
        """Why ``value`` cannot be set, or None when it can."""
        spec = _BY_NAME.get(name)
        if spec is None:
            return f"unknown parameter {name!r}"
        if not math.isfinite(value):
            return f"{name}: value {value!r} is not a finite number"
        if spec.is_int and value != int(value):
            return f"{name}: integer parameter, got {value!r}"
        if not spec.min <= value <= spec.max:
            return f"{name}: {value!r} outside {spec.min:g}..{spec.max:g}"
        return None

    def set(self, name: str, value: float) -> Param | None:
        """Set and return the new value; None (nothing changed) when unknown or invalid."""
        if self.validate(name, value) is not None:
            return None
        self._values[name] = float(int(value)) if _BY_NAME[name].is_int else float(value)
        return self.get(name)

"""The contract between the vehicle model and its MAVLink personality.

``flightsim.simulation.Simulation`` (physics, autopilot, sensors) implements
this; ``flightsim.mavlink`` (PX4-like MAVLink link) and ``flightsim.runner``
(clock, sockets, truth publishing) use only what is declared here. Units are
SI, frames are local NED with origin at home, angles in radians unless named
``_deg``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from typing import Literal, Protocol, runtime_checkable

from secuav_common.scenario import Home
from secuav_common.scenario import Vehicle as VehicleConfig

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # w, x, y, z; body -> NED


class FlightMode(StrEnum):
    """PX4 modes the vehicle offers (a subset of PX4's main/sub modes)."""

    MANUAL = "manual"  # disarmed default; PX4 reports MANUAL when idle on the ground
    POSITION = "position"
    HOLD = "hold"  # AUTO.LOITER
    TAKEOFF = "takeoff"
    LAND = "land"
    RTL = "rtl"
    MISSION = "mission"
    OFFBOARD = "offboard"


class LandedState(IntEnum):
    """MAV_LANDED_STATE values."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class Result(IntEnum):
    """MAV_RESULT values."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


@dataclass(frozen=True, slots=True)
class Outcome:
    result: Result
    reason: str = ""  # shown to the user as STATUSTEXT when not accepted, PX4 style

    @property
    def ok(self) -> bool:
        return self.result == Result.ACCEPTED


@dataclass(frozen=True, slots=True)
class State:
    """Kinematic state at sim time ``t_s`` (truth, or the vehicle's own estimate)."""

    t_s: float
    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    acc_ned_m_s2: Vec3
    quat: Quat
    euler_rad: Vec3  # roll, pitch, yaw
    rates_rad_s: Vec3  # body p, q, r


@dataclass(frozen=True, slots=True)
class OffboardSetpoint:
    """One SET_POSITION_TARGET_LOCAL_NED, already decoded from its type mask.

    ``None`` means "ignored" for that group. Velocities and accelerations in
    ``frame="body"`` are rotated by the current yaw (MAV_FRAME_BODY_NED).
    """

    pos_ned_m: Vec3 | None = None
    vel_m_s: Vec3 | None = None
    acc_m_s2: Vec3 | None = None
    yaw_rad: float | None = None
    yaw_rate_rad_s: float | None = None
    frame: Literal["ned", "body"] = "ned"


class NavCommand(IntEnum):
    """MAV_CMD values of the mission items the vehicle executes."""

    WAYPOINT = 16
    LOITER_UNLIM = 17
    LOITER_TIME = 19
    RETURN_TO_LAUNCH = 20
    LAND = 21
    TAKEOFF = 22


@dataclass(frozen=True, slots=True)
class NavItem:
    """A mission item in the local frame (the MAVLink layer converts lat/lon)."""

    command: NavCommand
    pos_ned_m: Vec3
    hold_s: float = 0.0
    acceptance_radius_m: float = 0.5
    yaw_rad: float | None = None
    speed_m_s: float | None = None  # horizontal cruise speed on the leg to this item; None: MPC_XY_CRUISE


@dataclass(frozen=True, slots=True)
class RangeReading:
    """One range measurement, ready to become a DISTANCE_SENSOR.

    ``distance_m`` is NaN when the sensor sees nothing in range or dropped out;
    the link then sends ``max_m`` + 1 cm as PX4 drivers do for "no target".
    """

    sensor_id: int
    t_s: float
    distance_m: float
    min_m: float
    max_m: float
    sensor_type: int  # MAV_DISTANCE_SENSOR
    orientation: int  # MAV_SENSOR_ORIENTATION
    noise_std_m: float


@dataclass(frozen=True, slots=True)
class GpsFix:
    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # AMSL
    vel_ned_m_s: Vec3
    eph_m: float
    epv_m: float
    satellites: int
    fix_type: int = 3  # GPS_FIX_TYPE_3D_FIX


@dataclass(frozen=True, slots=True)
class Param:
    name: str  # at most 16 characters, as MAVLink allows
    value: float
    is_int: bool = False  # MAV_PARAM_TYPE_INT32 vs REAL32


@dataclass(slots=True)
class Health:
    """Which subsystems are present and healthy (SYS_STATUS sensor bits)."""

    gyro: bool = True
    accel: bool = True
    mag: bool = True
    baro: bool = True
    gps: bool = True
    prearm_ok: bool = True
    failures: list[str] = field(default_factory=list)


class VehicleModel(Protocol):
    """What the MAVLink personality needs from one simulated vehicle."""

    config: VehicleConfig
    sysid: int
    home: Home

    @property
    def truth(self) -> State: ...
    @property
    def estimate(self) -> State: ...
    @property
    def armed(self) -> bool: ...
    @property
    def mode(self) -> FlightMode: ...
    @property
    def landed_state(self) -> LandedState: ...
    @property
    def crashed(self) -> bool: ...
    @property
    def health(self) -> Health: ...
    @property
    def battery(self) -> tuple[float, float]:
        """(voltage V, remaining 0..1)."""
        ...

    @property
    def mission_current(self) -> int: ...
    @property
    def mission_finished(self) -> bool: ...

    def arm(self) -> Outcome: ...
    def disarm(self, force: bool = False) -> Outcome: ...
    def takeoff(self, altitude_m: float | None = None) -> Outcome: ...
    def land(self) -> Outcome: ...
    def return_to_launch(self) -> Outcome: ...
    def set_mode(self, mode: FlightMode) -> Outcome: ...
    def offboard_setpoint(self, setpoint: OffboardSetpoint) -> None: ...
    def set_mission(self, items: list[NavItem]) -> Outcome: ...
    def set_mission_current(self, seq: int) -> Outcome: ...
    def params(self) -> list[Param]: ...
    def get_param(self, name: str) -> Param | None: ...
    def set_param(self, name: str, value: float) -> Param | None: ...
    def pop_readings(self) -> list[RangeReading]: ...
    def pop_gps(self) -> list[GpsFix]: ...
    def pop_status_texts(self) -> list[tuple[int, str]]:
        """(MAV_SEVERITY, text) events: crash, failsafe, mode refusals."""
        ...


@runtime_checkable
class Repositionable(Protocol):
    """Optional for a VehicleModel: MAV_CMD_DO_REPOSITION (MAVSDK ``goto_location``).

    Fly to ``pos_ned_m`` and hold there in HOLD mode, as PX4 does; the MAVLink
    layer answers UNSUPPORTED for vehicles without it.
    """

    def reposition(self, pos_ned_m: Vec3, yaw_rad: float | None = None) -> Outcome: ...


@runtime_checkable
class SpeedSettable(Protocol):
    """Optional for a VehicleModel: MAV_CMD_DO_CHANGE_SPEED (MAVSDK ``set_current_speed``).

    Sets the horizontal speed of mission legs and repositions until changed
    again; ``None`` goes back to MPC_XY_CRUISE and the items' own speeds.
    """

    def set_cruise_speed(self, speed_m_s: float | None) -> Outcome: ...


@dataclass(frozen=True, slots=True)
class ExternalRange:
    """A DISTANCE_SENSOR that arrived over MAVLink from a companion (not one the vehicle measured itself)."""

    src_sysid: int
    src_compid: int
    sensor_id: int
    distance_m: float
    orientation: int  # MAV_SENSOR_ORIENTATION


@dataclass(frozen=True, slots=True)
class ExternalPosition:
    """A position in the local NED frame from VISION_POSITION_ESTIMATE or ODOMETRY."""

    src_sysid: int
    src_compid: int
    pos_ned_m: Vec3
    message: Literal["vision_position_estimate", "odometry"]


@runtime_checkable
class ExternalInput(Protocol):
    """Optional for a VehicleModel: readings from a companion that its estimator fuses (scenario ``external``).

    Each call answers whether the reading was taken; False when the vehicle expects no such reading from that
    source (another system or component, an undeclared sensor id, a value out of range), as a real autopilot
    ignores what it was not configured for.
    """

    def external_range(self, reading: ExternalRange) -> bool: ...
    def external_position(self, fix: ExternalPosition) -> bool: ...

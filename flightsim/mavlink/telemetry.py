"""Telemetry messages built from the vehicle's ESTIMATE (never truth), as PX4 sends them.

Raw sensor messages (GPS_RAW_INT, DISTANCE_SENSOR) carry the sensor models'
own samples. ``time_boot_ms`` is sim time: the vehicle "booted" at t = 0.
"""

from __future__ import annotations

import math
import time

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import GpsFix, RangeReading, VehicleModel
from secuav_common.geo import ned_to_geodetic

MAV = mavlink.MAVLink
Message = mavlink.MAVLink_message

# SYS_STATUS sensor bits we report (MAV_SYS_STATUS_SENSOR)
GYRO, ACCEL, MAG, BARO = 0x1, 0x2, 0x4, 0x8
GPS = 0x20
MOTOR_OUTPUTS = 0x8000
AHRS = 0x200000
GEOFENCE = 0x100000  # healthy (no breach) though not present: MAVProxy prints "fence breach" otherwise
PREARM_CHECK = 0x10000000

# AUTOPILOT_VERSION.capabilities (MAV_PROTOCOL_CAPABILITY), PX4's set minus FTP and terrain
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)
# PX4 v1.14.0 release, encoded as PX4 does: major << 24 | minor << 16 | patch << 8 | type (255 = release)
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255
UINT16_MAX = 0xFFFF


def _clamp_u16(value: float) -> int:
    return max(0, min(UINT16_MAX - 1, round(value)))


def _clamp_i16(value: float) -> int:
    return max(-32767, min(32767, round(value)))


class TelemetryBuilder:
    """Builds one message of a given id for one vehicle."""

    def __init__(self, vehicle: VehicleModel, mav: MAV) -> None:
        self.v = vehicle
        self.mav = mav
        self.home = vehicle.home
        self.last_gps: GpsFix | None = None
        self._epoch_us = int(time.time() * 1e6)  # SYSTEM_TIME only: wall clock at boot + sim time
        self._builders = {
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self.battery_status,
            mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: self.system_time,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_int,
            mavlink.MAVLINK_MSG_ID_ALTITUDE: self.altitude,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self.vfr_hud,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
        }

    def can_build(self, msg_id: int) -> bool:
        return msg_id in self._builders

    def build(self, msg_id: int, t_s: float) -> Message | None:
        """The message, or None when there is nothing to say yet (no GPS fix)."""
        return self._builders[msg_id](t_s)

    # -- state ---------------------------------------------------------------------------
    def sys_status(self, t_s: float) -> Message:
        h = self.v.health
        present = GYRO | ACCEL | MAG | BARO | GPS | MOTOR_OUTPUTS | AHRS | PREARM_CHECK
        enabled = present if self.v.armed else present & ~MOTOR_OUTPUTS
        healthy = MOTOR_OUTPUTS | AHRS | GEOFENCE
        for bit, ok in ((GYRO, h.gyro), (ACCEL, h.accel), (MAG, h.mag), (BARO, h.baro), (GPS, h.gps)):
            if ok:
                healthy |= bit
        if h.prearm_ok:
            healthy |= PREARM_CHECK
        if not h.gps:
            present &= ~GPS
            enabled &= ~GPS
        volt, remaining = self.v.battery
        return self.mav.sys_status_encode(
            present, enabled, healthy, 200, _clamp_u16(volt * 1000), -1, round(remaining * 100), 0, 0, 0, 0, 0, 0
        )

    def extended_sys_state(self, t_s: float) -> Message:
        return self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.v.landed_state))

    def battery_status(self, t_s: float) -> Message:
        volt, remaining = self.v.battery
        voltages = [_clamp_u16(volt * 1000)] + [UINT16_MAX] * 9
        return self.mav.battery_status_encode(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            32767,  # INT16_MAX: temperature unknown
            voltages,
            -1,
            -1,
            -1,
            round(remaining * 100),
        )

    def system_time(self, t_s: float) -> Message:
        return self.mav.system_time_encode(self._epoch_us + round(t_s * 1e6), round(t_s * 1000))

    # -- estimate --------------------------------------------------------------------------
    def attitude(self, t_s: float) -> Message:
        e = self.v.estimate
        r, p, y = e.euler_rad
        return self.mav.attitude_encode(round(t_s * 1000), r, p, y, *e.rates_rad_s)

    def attitude_quaternion(self, t_s: float) -> Message:
        e = self.v.estimate
        return self.mav.attitude_quaternion_encode(round(t_s * 1000), *e.quat, *e.rates_rad_s)

    def local_position_ned(self, t_s: float) -> Message:
        e = self.v.estimate
        return self.mav.local_position_ned_encode(round(t_s * 1000), *e.pos_ned_m, *e.vel_ned_m_s)

    def global_position_int(self, t_s: float) -> Message:
        e = self.v.estimate
        n, east, d = e.pos_ned_m
        lat, lon, alt = ned_to_geodetic(self.home, n, east, d)
        vn, ve, vd = e.vel_ned_m_s
        hdg = round(math.degrees(e.euler_rad[2]) % 360.0 * 100) % 36000
        return self.mav.global_position_int_encode(
            round(t_s * 1000),
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000),
            round(-d * 1000),
            _clamp_i16(vn * 100),
            _clamp_i16(ve * 100),
            _clamp_i16(vd * 100),
            hdg,
        )

    def altitude(self, t_s: float) -> Message:
        e = self.v.estimate
        height = -e.pos_ned_m[2]  # the scenario's ground is the NED origin's plane
        amsl = self.home.alt_m + height
        return self.mav.altitude_encode(round(t_s * 1e6), amsl, amsl, height, height, height, height)

    def vfr_hud(self, t_s: float) -> Message:
        e = self.v.estimate
        vn, ve, vd = e.vel_ned_m_s
        speed = math.hypot(vn, ve)
        heading = round(math.degrees(e.euler_rad[2]) % 360.0) % 360
        throttle = 50 if self.v.armed and not self.v.crashed else 0
        return self.mav.vfr_hud_encode(speed, speed, heading, throttle, self.home.alt_m - e.pos_ned_m[2], -vd)

    def home_position(self, t_s: float) -> Message:
        h = self.home
        return self.mav.home_position_encode(
            round(h.lat_deg * 1e7),
            round(h.lon_deg * 1e7),
            round(h.alt_m * 1000),
            0.0,
            0.0,
            0.0,
            (1.0, 0.0, 0.0, 0.0),
            0.0,
            0.0,
            0.0,
            round(t_s * 1e6),
        )

    def autopilot_version(self, t_s: float) -> Message:
        sysid = self.v.sysid
        return self.mav.autopilot_version_encode(
            CAPABILITIES,
            FLIGHT_SW_VERSION,
            FLIGHT_SW_VERSION,
            0,
            0,
            b"\0" * 8,
            b"\0" * 8,
            b"\0" * 8,
            0,
            0,
            0x5EC0A70000 + sysid,  # "SECUAV" + sysid: unique per vehicle, stable across runs
        )

    # -- sensors -----------------------------------------------------------------------------
    def gps_raw_int(self, t_s: float) -> Message | None:
        fix = self.last_gps
        if fix is None:
            return None
        vn, ve, _vd = fix.vel_ned_m_s
        cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100) % 36000
        return self.mav.gps_raw_int_encode(
            round(fix.t_s * 1e6),
            fix.fix_type,
            round(fix.lat_deg * 1e7),
            round(fix.lon_deg * 1e7),
            round(fix.alt_m * 1000),
            _clamp_u16(fix.eph_m * 100),
            _clamp_u16(fix.epv_m * 100),
            _clamp_u16(math.hypot(vn, ve) * 100),
            cog,
            fix.satellites,
        )

    def distance_sensor(self, r: RangeReading) -> Message:
        max_cm = _clamp_u16(r.max_m * 100)
        if math.isfinite(r.distance_m):
            current_cm, quality = _clamp_u16(r.distance_m * 100), 100
        else:
            current_cm, quality = min(UINT16_MAX - 1, max_cm + 1), 0  # PX4 drivers' "no target"
        std_cm = r.noise_std_m * 100
        covariance = min(254, round(std_cm * std_cm))  # cm^2; 255 would mean "unknown"
        return self.mav.distance_sensor_encode(
            round(r.t_s * 1000),
            _clamp_u16(r.min_m * 100),
            max_cm,
            current_cm,
            r.sensor_type,
            r.sensor_id,
            r.orientation,
            covariance,
            signal_quality=quality,
        )

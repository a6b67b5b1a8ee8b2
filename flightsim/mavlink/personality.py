"""One vehicle's PX4 personality over MAVLink 2, without I/O.

``receive(datagram, now_wall_s)`` feeds what arrived; ``tick(now_wall_s)``
runs after the simulation advanced (sim time is read from the vehicle);
encoded frames leave through the ``send`` callback given at construction.
The asyncio edge (:mod:`flightsim.mavlink.udp`) owns the socket, so every
branch here can be driven by a test without a network.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import ExternalInput, ExternalRange, FlightMode, Outcome, Result, VehicleModel
from flightsim.mavlink import commands, external, ftp, modes, offboard
from flightsim.mavlink.missions import MissionServer
from flightsim.mavlink.parameters import ParamServer
from flightsim.mavlink.streams import StreamTable
from flightsim.mavlink.telemetry import TelemetryBuilder
from flightsim.mavlink.wire import Decoder, Encoder

log = logging.getLogger(__name__)
Message = mavlink.MAVLink_message

HEARTBEAT_PERIOD_S = 1.0
STATUSTEXT_LEN = 50
_AUTO_MODES = {FlightMode.HOLD, FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RTL, FlightMode.MISSION}
_GUIDED_MODES = _AUTO_MODES | {FlightMode.POSITION, FlightMode.OFFBOARD}
_PARAM_MSGS = {"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"}
_MISSION_MSGS = {
    "MISSION_COUNT",
    "MISSION_ITEM_INT",
    "MISSION_ITEM",
    "MISSION_REQUEST_LIST",
    "MISSION_REQUEST_INT",
    "MISSION_REQUEST",
    "MISSION_CLEAR_ALL",
    "MISSION_SET_CURRENT",
    "MISSION_ACK",
}


@dataclass(slots=True)
class LinkStats:
    rx_frames: int = 0
    rx_malformed: int = 0
    rx_ignored: int = 0  # valid frames addressed to another system, or from ourselves
    tx_frames: int = 0
    commands: int = 0
    commands_refused: int = 0
    offboard_setpoints: int = 0
    offboard_rejected: int = 0
    external_taken: int = 0  # a companion's readings the vehicle's estimator took (scenario ``external``)
    external_ignored: int = 0  # DISTANCE_SENSOR, vision, odometry it does not expect: source, id, frame


class Px4Personality:
    def __init__(self, vehicle: VehicleModel, send: Callable[[bytes], None]) -> None:
        self.vehicle = vehicle
        self.sysid = vehicle.sysid
        self._send_bytes = send
        self.encoder = Encoder(self.sysid)
        self.decoder = Decoder()
        mav = self.encoder.mav
        self.streams = StreamTable()
        self.telemetry = TelemetryBuilder(vehicle, mav)
        self.params = ParamServer(vehicle, mav, self.send, self.say)
        self.missions = MissionServer(vehicle, mav, self.send, self.say)
        self.stats = LinkStats()
        self._next_heartbeat_s = 0.0
        self._announced: tuple[bool, FlightMode, bool] | None = None
        self._last_range_t: dict[int, float] = {}
        self._status_id = 0
        self._wall_s = 0.0
        self._t_s = 0.0

    @property
    def now_s(self) -> float:
        """Sim time of the last tick (MAVLink time_boot_ms is this, in ms)."""
        return self._t_s

    # -- out ---------------------------------------------------------------------------------
    def send(self, msg: Message) -> None:
        self._send_bytes(self.encoder.pack(msg))
        self.stats.tx_frames += 1

    def say(self, severity: int, text: str) -> None:
        """STATUSTEXT, split into 50-character chunks sharing an id as MAVLink 2 allows."""
        data = text.encode("utf-8", "replace")
        if len(data) <= STATUSTEXT_LEN:
            self.send(self.encoder.mav.statustext_encode(severity, data))
            return
        self._status_id = self._status_id % 0xFFFF + 1
        chunks = [data[i : i + STATUSTEXT_LEN] for i in range(0, len(data), STATUSTEXT_LEN)]
        for n, chunk in enumerate(chunks):
            self.send(self.encoder.mav.statustext_encode(severity, chunk, self._status_id, n))

    def heartbeat(self) -> None:
        v = self.vehicle
        mode = v.mode
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if mode in _GUIDED_MODES:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if mode in _AUTO_MODES:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if v.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if v.crashed:
            status = mavlink.MAV_STATE_EMERGENCY
        elif v.armed:
            status = mavlink.MAV_STATE_ACTIVE
        else:
            status = mavlink.MAV_STATE_STANDBY
        self.send(
            self.encoder.mav.heartbeat_encode(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, modes.custom_mode(mode), status
            )
        )
        self._announced = (v.armed, mode, v.crashed)

    def request_message(self, msg_id: int, param2: float) -> bool:
        """Send one message now (MAV_CMD_REQUEST_MESSAGE); False if we cannot build it."""
        t = self.now_s
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            self.heartbeat()
        elif msg_id == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
            self.send(self.missions.mission_current_msg())
        elif msg_id == mavlink.MAVLINK_MSG_ID_MESSAGE_INTERVAL:
            target = round(param2) if math.isfinite(param2) else -1
            if not 0 <= target <= 0xFFFF:
                return False
            self.send(self.encoder.mav.message_interval_encode(target, self.streams.interval_us(target)))
        elif self.telemetry.can_build(msg_id):
            msg = self.telemetry.build(msg_id, t)
            if msg is None:
                return False
            self.send(msg)
        else:
            return False
        return True

    # -- in ----------------------------------------------------------------------------------
    def receive(self, datagram: bytes, now_wall_s: float) -> None:
        self._wall_s = now_wall_s
        before = self.decoder.stats.malformed
        for msg in self.decoder.decode(datagram):
            self.stats.rx_frames += 1
            if not self._for_us(msg):
                self.stats.rx_ignored += 1
                continue
            try:
                self._handle(msg, now_wall_s)
            except Exception:  # a message we mis-handle must never stop the vehicle
                log.exception("mavlink.handler_failed", extra={"sysid": self.sysid, "mav_msg": msg.get_type()})
        self.stats.rx_malformed += self.decoder.stats.malformed - before
        self._announce_changes()

    def _for_us(self, msg: Message) -> bool:
        if msg.get_srcSystem() == self.sysid and msg.get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1:
            return False  # our own frames echoed back
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.sysid):
            return False
        comp = getattr(msg, "target_component", 0)
        return comp in (0, mavlink.MAV_COMP_ID_AUTOPILOT1)

    def _handle(self, msg: Message, now_wall_s: float) -> None:
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(msg)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._offboard(offboard.decode_local(msg))
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
            self._offboard(offboard.decode_global(msg, self.vehicle.home))
        elif kind == "SET_ATTITUDE_TARGET":
            # MAVSDK set_attitude / set_attitude_rate: refused out loud, so offboard.start() fails with a reason.
            self._offboard("offboard: attitude setpoints are not supported, use position or velocity")
        elif kind in _PARAM_MSGS:
            self.params.handle(msg)
        elif kind in _MISSION_MSGS:
            self.missions.handle(msg, now_wall_s)
        elif kind == "SET_MODE":
            mode = modes.decode_custom_mode(msg.custom_mode)
            # FlightMode is a StrEnum, so the refusal reason is told apart by type, not by str.
            outcome = self.vehicle.set_mode(mode) if isinstance(mode, FlightMode) else Outcome(Result.DENIED, mode)
            self._report(outcome)
        elif kind == "FILE_TRANSFER_PROTOCOL":
            reply = ftp.answer(msg, self.encoder.mav)
            if reply is not None:
                self.send(reply)
        elif kind in external.MESSAGES:
            self._external(msg)
        elif kind == "TIMESYNC" and msg.tc1 == 0:
            self.send(self.encoder.mav.timesync_encode(round(self.now_s * 1e9), msg.ts1))

    def _external(self, msg: Message) -> None:
        v = self.vehicle
        reading = external.decode(msg)
        taken = False
        if reading is not None and isinstance(v, ExternalInput):
            taken = v.external_range(reading) if isinstance(reading, ExternalRange) else v.external_position(reading)
        if taken:
            self.stats.external_taken += 1
        else:
            self.stats.external_ignored += 1

    def _command(self, msg: Message) -> None:
        cmd = commands.Command.from_message(msg)
        self.stats.commands += 1
        try:
            outcome = commands.dispatch(self, cmd)
        except (ValueError, OverflowError, TypeError, struct.error) as exc:
            # A malformed command must still be answered, or MAVSDK retries and times out.
            outcome = Outcome(Result.FAILED, f"command {cmd.command} rejected: {exc}")
        if not outcome.ok:
            self.stats.commands_refused += 1
        self.send(
            self.encoder.mav.command_ack_encode(
                cmd.command, int(outcome.result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )
        self._report(outcome)

    def _report(self, outcome: Outcome) -> None:
        """Send the vehicle's own status texts, then the refusal reason unless it already said it."""
        said = self._flush_status_texts()
        if not outcome.ok and outcome.reason and outcome.reason not in said:
            severity = (
                mavlink.MAV_SEVERITY_CRITICAL if outcome.result == Result.DENIED else mavlink.MAV_SEVERITY_WARNING
            )
            self.say(severity, outcome.reason)

    def _offboard(self, decoded: object) -> None:
        if isinstance(decoded, str):
            self.stats.offboard_rejected += 1
            if self.stats.offboard_rejected in (1, 10, 100) or self.stats.offboard_rejected % 1000 == 0:
                self.say(mavlink.MAV_SEVERITY_WARNING, decoded)  # not once per setpoint: they stream at 20+ Hz
            return
        self.stats.offboard_setpoints += 1
        self.vehicle.offboard_setpoint(decoded)  # type: ignore[arg-type]

    # -- time ----------------------------------------------------------------------------------
    def tick(self, sim_t_s: float, now_wall_s: float) -> None:
        """Send what is due at sim time ``sim_t_s`` (the simulation has just advanced to it)."""
        self._wall_s = now_wall_s
        self._t_s = t = sim_t_s
        if t + 1e-9 >= self._next_heartbeat_s:
            self.heartbeat()
            self._next_heartbeat_s = max(self._next_heartbeat_s + HEARTBEAT_PERIOD_S, t)
        self._flush_status_texts()
        self._announce_changes()
        fixes = self.vehicle.pop_gps()
        if fixes:
            self.telemetry.last_gps = fixes[-1]
        for msg_id in self.streams.due(t):
            if msg_id == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
                if self.missions.plan.items:
                    self.send(self.missions.mission_current_msg())
                continue
            msg = self.telemetry.build(msg_id, t)
            if msg is not None:
                self.send(msg)
        self._send_ranges()
        self.params.pump()
        self.missions.pump(now_wall_s)
        self.missions.track_progress()

    def _send_ranges(self) -> None:
        readings = self.vehicle.pop_readings()
        throttle = self.streams.event_interval_s.get(mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR)
        for r in readings:
            if throttle is not None:
                if math.isinf(throttle) or r.t_s - self._last_range_t.get(r.sensor_id, -math.inf) < throttle - 1e-9:
                    continue
                self._last_range_t[r.sensor_id] = r.t_s
            self.send(self.telemetry.distance_sensor(r))

    def _flush_status_texts(self) -> list[str]:
        texts = self.vehicle.pop_status_texts()
        for severity, text in texts:
            self.say(severity, text)
        return [t for _, t in texts]

    def _announce_changes(self) -> None:
        """An extra HEARTBEAT right after any arming or mode change: MAVSDK reads state from it."""
        v = self.vehicle
        if self._announced is not None and self._announced != (v.armed, v.mode, v.crashed):
            self.heartbeat()

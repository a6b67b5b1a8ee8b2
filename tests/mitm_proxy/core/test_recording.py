"""Recordings: both .tlog files read back by pymavlink's own tlog reader; the index names changed frames."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from attack_profiles.profile import parse_profile
from mavframe import codec
from mavframe.packet import Direction, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.recorder import Recorder
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import HEARTBEAT, distance, heartbeat, local_position, mav, pack


def read_tlog(path: Path) -> list[Any]:
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    out = []
    while True:
        msg = conn.recv_match()
        if msg is None:
            break
        if msg.get_type() != "BAD_DATA":
            out.append(msg)
    conn.close()
    return out


def test_original_and_forwarded_read_back_with_the_attack_visible(tmp_path: Path) -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(parse_profile({"name": "wall", "rules": [
        {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "bias", "offset_m": 1.5},
        {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 1}, "kind": "drop"},
        {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 2}, "kind": "delay", "delay_s": 0.25},
    ]}, "wall.yaml"))  # fmt: skip
    rec = Recorder(tmp_path / "rec", link=0)
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1), observers=[rec])
    m = mav()
    sent = [
        pack(heartbeat(), m) + pack(local_position(), m),
        pack(distance(cm=400, sensor_id=0), m) + pack(distance(cm=400, sensor_id=1), m),
        b"garbage" + pack(distance(cm=400, sensor_id=2), m),
        pack(heartbeat(), m, v1=True),
    ]
    t0 = time.time()
    for d in sent:
        pipe.feed(d, Direction.DOWNLINK, time.monotonic())
    rec.close()
    rec.close()  # idempotent

    original = read_tlog(tmp_path / "rec" / "original.tlog")
    forwarded = read_tlog(tmp_path / "rec" / "forwarded.tlog")
    assert [x.get_type() for x in original] == [
        "HEARTBEAT", "LOCAL_POSITION_NED", "DISTANCE_SENSOR", "DISTANCE_SENSOR", "DISTANCE_SENSOR", "HEARTBEAT",
    ]  # fmt: skip
    assert [x.current_distance for x in original if x.get_type() == "DISTANCE_SENSOR"] == [400, 400, 400]
    assert [(x.get_type(), x.id if x.get_type() == "DISTANCE_SENSOR" else None) for x in forwarded] == [
        ("HEARTBEAT", None), ("LOCAL_POSITION_NED", None), ("DISTANCE_SENSOR", 0), ("DISTANCE_SENSOR", 2),
        ("HEARTBEAT", None),
    ]  # fmt: skip
    assert forwarded[2].current_distance == 550 and forwarded[3].current_distance == 400
    # tlog timestamps are wall-clock seconds; the delayed frame is stamped with its release time.
    assert all(t0 - 1 < x._timestamp < t0 + 5 for x in original)
    assert forwarded[3]._timestamp - forwarded[2]._timestamp > 0.2

    index = json.loads((tmp_path / "rec" / "index.json").read_text())
    assert index == [
        {"index": 2, "original": 2, "msgid": 132, "direction": "downlink", "changed": True, "injected": False,
         "dropped": False, "delay_s": 0.0, "notes": ["attack:wall:rules[0]"]},
        {"index": None, "original": 3, "msgid": 132, "direction": "downlink", "changed": False, "injected": False,
         "dropped": True, "delay_s": 0.0, "notes": ["attack:wall:rules[1]"]},
        {"index": 3, "original": 4, "msgid": 132, "direction": "downlink", "changed": False, "injected": False,
         "dropped": False, "delay_s": 0.25, "notes": ["attack:wall:rules[2]"]},
    ]  # fmt: skip


def test_forwarded_untouched_stream_is_byte_identical_to_the_original(tmp_path: Path) -> None:
    with Recorder(tmp_path) as rec:
        pipe = Pipeline(0, [], stats=LinkStats(), observers=[rec])
        m = mav()
        for i in range(50):
            pipe.feed(pack(distance(cm=i, sensor_id=i % 5), m) + pack(heartbeat(), m), Direction.DOWNLINK, 0.0)
        pipe.feed(pack(heartbeat(), mav(sysid=255, compid=190)), Direction.UPLINK, 0.0)
    orig = (tmp_path / "original.tlog").read_bytes()
    fwd = (tmp_path / "forwarded.tlog").read_bytes()

    def frames_only(blob: bytes) -> list[bytes]:
        out, i = [], 0
        while i < len(blob):
            i += 8
            n = blob[i + 1] + 12
            out.append(blob[i : i + n])
            i += n
        return out

    assert frames_only(orig) == frames_only(fwd) and len(frames_only(orig)) == 101
    assert json.loads((tmp_path / "index.json").read_text()) == []
    msgs = read_tlog(tmp_path / "forwarded.tlog")
    assert sum(x.get_msgId() == HEARTBEAT for x in msgs) == 51


def test_recording_is_flushed_while_running_so_a_crash_keeps_it(tmp_path: Path) -> None:
    clock = [1_700_000_000.0]
    rec = Recorder(tmp_path, wall_clock=lambda: clock[0])
    pipe = Pipeline(0, [], stats=LinkStats(), observers=[rec])
    frame = pack(heartbeat())
    pipe.feed(frame, Direction.DOWNLINK, 0.0)
    assert (tmp_path / "original.tlog").stat().st_size == 0  # buffered
    clock[0] += 1.5
    pipe.feed(frame, Direction.DOWNLINK, 0.0)
    # The first second reaches the disk (the writer thread flushes it; wait for that, not for a time).
    deadline = time.monotonic() + 10.0
    while (tmp_path / "original.tlog").stat().st_size != 8 + len(frame) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert (tmp_path / "original.tlog").stat().st_size == 8 + len(frame)
    assert (tmp_path / "forwarded.tlog").read_bytes()[:8] == int(1_700_000_000.0 * 1e6).to_bytes(8, "big")
    rec.close()
    assert (tmp_path / "original.tlog").stat().st_size == 2 * (8 + len(frame))


class Beacon:
    """A real stage that adds a STATUSTEXT after each HEARTBEAT."""

    name = "beacon"
    active = True
    message_ids = frozenset({HEARTBEAT})

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        extra = codec.build("STATUSTEXT", {"severity": 6, "text": "beacon"}, sysid=1, compid=1, seq=0,
                            direction=pkt.direction, link=0, now_s=now_s)  # fmt: skip
        extra.notes.append("beacon")
        return [pkt, extra]


def test_injected_frames_are_indexed_without_an_original(tmp_path: Path) -> None:
    with Recorder(tmp_path) as rec:
        pipe = Pipeline(0, [Beacon()], stats=LinkStats(), observers=[rec])
        pipe.feed(pack(local_position()) + pack(heartbeat()), Direction.UPLINK, 0.0)
    index = json.loads((tmp_path / "index.json").read_text())
    assert index == [{"index": 2, "original": None, "msgid": 253, "direction": "uplink", "changed": False,
                      "injected": True, "dropped": False, "delay_s": 0.0, "notes": ["beacon"]}]  # fmt: skip
    msgs = read_tlog(tmp_path / "forwarded.tlog")
    assert [m.get_type() for m in msgs] == ["LOCAL_POSITION_NED", "HEARTBEAT", "STATUSTEXT"]
    assert msgs[2].text == "beacon"


def test_a_full_disk_stops_the_recording_once_and_never_changes_what_is_forwarded(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """--record onto a full disk: the hostile review saw 19,880 of 20,000 frames go out raw; now none."""
    caplog.set_level(logging.ERROR)
    for name in ("original.tlog", "forwarded.tlog", "index.json"):  # every write fails: ENOSPC
        (tmp_path / name).symlink_to("/dev/full")
    rec = Recorder(tmp_path)
    profile = parse_profile({"name": "plus", "rules": [{"target": {"message": "DISTANCE_SENSOR"}, "kind": "bias",
                                                        "offset": 1.0}]})  # fmt: skip
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(profile)
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(), observers=[rec])
    sender = mav(1)
    outs = []
    for i in range(2000):
        rec.flush()  # push every chunk to the (full) disk at once
        outs += pipe.feed(pack(distance(cm=250, t_ms=i), sender), Direction.DOWNLINK, time.monotonic())
    rec.close()
    parser = mavutil.mavlink.MAVLink(None)
    decoded = [parser.decode(bytearray(o.data)).current_distance for o in outs]
    assert decoded == [350] * 2000  # every frame went through the attack stage
    assert rec.failed is not None and "No space left" in rec.failed
    assert sum(r.getMessage() == "record.failed" for r in caplog.records) == 1

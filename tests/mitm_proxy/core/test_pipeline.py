"""The pipeline: byte-exact forwarding by default, stages only on what they target, everything counted."""

from __future__ import annotations

import time
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from mavframe import codec
from mavframe.frames import CRC_EXTRA, split
from mavframe.packet import Direction, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import HOSTILE_BYTES_PER_S, Outgoing
from tests.support.frames_support import (
    DISTANCE_SENSOR,
    HEARTBEAT,
    distance,
    frames,
    garbage,
    heartbeat,
    local_position,
    mav,
    pack,
    parse_all,
    unknown_frame,
)
from tests.support.pipelines import bias, make, profile

DOWN = Direction.DOWNLINK
UP = Direction.UPLINK


def test_untargeted_datagram_leaves_as_the_same_object() -> None:
    pipe, stats, _ = make(bias())
    m = mav()
    dgram = pack(heartbeat(), m) + pack(local_position(), m)
    out = pipe.feed(dgram, DOWN, 5.0)
    assert len(out) == 1 and out[0].data is dgram and out[0].release_s == 5.0 and out[0].frames == 2
    s = stats[DOWN]
    assert (s.frames_in, s.frames_out, s.bytes_in, s.bytes_out, s.datagrams_in) == (2, 2, len(dgram), len(dgram), 1)


def test_no_profile_means_the_stage_is_inactive_and_targeted_ids_pass_too() -> None:
    pipe, _, stage = make()
    dgram = pack(distance())
    assert not stage.active
    assert pipe.feed(dgram, DOWN, time.monotonic())[0].data is dgram


def test_bias_rewrites_only_the_targeted_sensor_and_keeps_order_and_headers() -> None:
    pipe, stats, _ = make(bias(sensor_id=0, offset_m=2.0))
    m = mav(sysid=1, compid=1, seq=10)
    hb, d0, d1 = pack(heartbeat(), m), pack(distance(cm=500, sensor_id=0), m), pack(distance(cm=500, sensor_id=1), m)
    (out,) = pipe.feed(hb + d0 + d1, DOWN, time.monotonic())
    msgs = parse_all(out.data)
    assert [x.get_msgId() for x in msgs] == [HEARTBEAT, DISTANCE_SENSOR, DISTANCE_SENSOR]
    assert [x.get_seq() for x in msgs] == [10, 11, 12]
    assert msgs[1].current_distance == 700 and msgs[2].current_distance == 500
    assert out.data.startswith(hb) and out.data.endswith(d1)  # untouched frames byte for byte
    assert stats[DOWN].rewritten == 1 and stats[DOWN].frames_out == 3


def test_direction_matters() -> None:
    pipe, stats, _ = make(bias(sensor_id=0, direction="downlink"))
    dgram = pack(distance(cm=500))
    assert pipe.feed(dgram, UP, time.monotonic())[0].data == dgram
    assert stats[UP].rewritten == 0


def test_drop_is_counted_and_nothing_is_sent() -> None:
    pipe, stats, _ = make({"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "drop"})
    hb = pack(heartbeat())
    assert pipe.feed(pack(distance()), DOWN, time.monotonic()) == []
    (out,) = pipe.feed(pack(distance()) + hb, DOWN, time.monotonic())
    assert out.data == hb
    assert stats[DOWN].dropped == 2 and stats[DOWN].frames_out == 1


def test_delay_becomes_a_separate_item_with_a_future_release() -> None:
    pipe, stats, _ = make({"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "delay", "delay_s": 0.5})
    hb, d = pack(heartbeat()), pack(distance())
    now = time.monotonic()
    out = pipe.feed(hb + d, DOWN, now)
    assert out == [Outgoing(hb, now, now, 1), Outgoing(d, now + 0.5, now, 1)]
    assert stats[DOWN].delayed == 1


def test_bypass_switch() -> None:
    pipe, _, stage = make(bias())
    dgram = pack(distance(cm=500))
    stage.active = False
    assert pipe.feed(dgram, DOWN, time.monotonic())[0].data is dgram
    stage.active = True
    assert parse_all(pipe.feed(dgram, DOWN, time.monotonic())[0].data)[0].current_distance == 700


def test_profile_swap_takes_effect_between_two_datagrams() -> None:
    pipe, _, stage = make(bias(offset_m=1.0))
    dgram = pack(distance(cm=500))
    assert parse_all(pipe.feed(dgram, DOWN, time.monotonic())[0].data)[0].current_distance == 600
    AttackSwitch(stage.slot).offer(profile(bias(offset_m=3.0)))
    assert parse_all(pipe.feed(dgram, DOWN, time.monotonic())[0].data)[0].current_distance == 800
    AttackSwitch(stage.slot).offer(None)
    assert pipe.feed(dgram, DOWN, time.monotonic())[0].data is dgram


def test_garbage_is_stripped_counted_and_valid_frames_survive() -> None:
    pipe, stats, _ = make()
    a, b = pack(heartbeat()), pack(distance())
    (out,) = pipe.feed(b"xx" + a + b"\xfd\x01" + b, DOWN, time.monotonic())
    assert out.data == a + b
    assert stats[DOWN].bad == {"garbage": 1, "bad_flags": 1}
    assert pipe.feed(b"just garbage", DOWN, time.monotonic()) == []
    assert pipe.feed(b"", DOWN, time.monotonic()) == []
    assert stats[DOWN].datagrams_in == 3 and stats[DOWN].frames_out == 2


def test_past_the_hostile_budget_garbage_is_dropped_unsplit_and_frames_still_pass() -> None:
    pipe, stats, _ = make()
    junk = bytes([0xFD, 9, 0, 0, 0, 1, 1, 0, 0, 0]) * 800  # 8 kB of overlapping HEARTBEAT headers, none valid
    valid = pack(heartbeat()) + pack(distance())
    t = 100.0
    sent = 0
    while sent <= HOSTILE_BYTES_PER_S:
        assert pipe.feed(junk, DOWN, t) == []
        sent += len(junk)
    before = dict(stats[DOWN].bad)
    assert "over_budget" not in before  # every one of those was split and counted by its reason
    assert pipe.feed(junk, DOWN, t + 0.5) == []
    (out,) = pipe.feed(valid, DOWN, t + 0.5)  # whole frames pass, budget or not
    assert out.data == valid
    assert stats[DOWN].bad["over_budget"] == 1 and dict(stats[DOWN].bad, over_budget=0) == {**before, "over_budget": 0}
    assert stats[UP].bad == {}  # the other direction has its own budget
    assert pipe.feed(junk, DOWN, t + 1.01) == []  # a new second: split (and counted by reason) again
    assert stats[DOWN].bad["over_budget"] == 1 and sum(stats[DOWN].bad.values()) > sum(before.values()) + 1


def test_unknown_ids_are_forwarded_and_counted() -> None:
    pipe, stats, _ = make(bias())
    u = unknown_frame()
    assert pipe.feed(u, DOWN, time.monotonic())[0].data is u
    assert stats[DOWN].unknown == 1


class Beacon:
    """A real stage: after every HEARTBEAT it injects a DISTANCE_SENSOR reading (id 99)."""

    name = "beacon"
    active = True
    message_ids = frozenset({HEARTBEAT})

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        # 1-1000 cm: the attacked 1.42 m is still a reading (an attack stays inside the sensor's range)
        fields = {"time_boot_ms": 1, "min_distance": 1, "max_distance": 1000, "current_distance": 42, "type": 0,
                  "id": 99, "orientation": 0, "covariance": 0}  # fmt: skip
        h = pkt.header
        extra = codec.build("DISTANCE_SENSOR", fields, sysid=h.sysid, compid=h.compid, seq=h.seq,
                            direction=pkt.direction, link=pkt.link, now_s=now_s)  # fmt: skip
        return [pkt, extra]


class Broken:
    """A stage with a bug: the pipeline must keep forwarding."""

    name = "broken"
    active = True
    message_ids = frozenset({DISTANCE_SENSOR})

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        raise RuntimeError("bug")


def test_injected_frames_follow_their_trigger_and_pass_later_stages() -> None:
    pipe, stats, _ = make(bias(sensor_id=99, offset_m=1.0))
    pipe.stages.insert(0, Beacon())  # before the attack stage: the attack sees the injected reading
    hb = pack(heartbeat())
    (out,) = pipe.feed(hb, DOWN, time.monotonic())
    msgs = parse_all(out.data)
    assert out.data.startswith(hb) and [x.get_msgId() for x in msgs] == [HEARTBEAT, DISTANCE_SENSOR]
    assert msgs[1].current_distance == 142 and msgs[1].id == 99
    assert stats[DOWN].injected == 1 and stats[DOWN].rewritten == 0 and stats[DOWN].frames_out == 2


def test_a_failing_stage_forwards_the_frame_as_it_came(caplog: pytest.LogCaptureFixture) -> None:
    pipe, stats, _ = make(extra=[Broken()])
    d = pack(distance())
    for _ in range(3):
        assert pipe.feed(d, DOWN, time.monotonic())[0].data == d
    assert stats[DOWN].bad == {"stage_error": 3} and stats[DOWN].dropped == 0
    assert sum(r.message == "pipeline.stage_error" for r in caplog.records) == 1  # logged once, not per frame


def test_encode_error_forwards_the_original() -> None:
    # A scale so large that current_distance leaves uint16: the engine clamps it, so force a bad value by hand.
    class Overflow:
        name = "overflow"
        active = True
        message_ids = frozenset({DISTANCE_SENSOR})

        def process(self, pkt: Packet, now_s: float) -> list[Packet]:
            codec.decode(pkt)["current_distance"] = 1 << 20
            pkt.changed = True
            return [pkt]

    pipe, stats, _ = make(extra=[Overflow()])
    d = pack(distance())
    assert pipe.feed(d, DOWN, time.monotonic())[0].data == d
    assert stats[DOWN].bad == {"encode_error": 1} and stats[DOWN].rewritten == 0


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MIXED = [
    {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "bias", "offset_m": 0.5},
    {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 1}, "kind": "drop"},
    {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 2}, "kind": "delay", "delay_s": 0.1},
]


@FUZZ
@given(
    st.lists(
        st.tuples(garbage, st.one_of(frames(), st.builds(lambda i: pack(distance(sensor_id=i)), st.integers(0, 3)))),
        min_size=1,
        max_size=10,
    ),
    st.booleans(),
)
def test_fuzz_counters_balance_and_nothing_valid_is_lost(chunks: list[tuple[bytes, bytes]], beacon: bool) -> None:
    data = b"".join(g + f for g, f in chunks)
    valid = [f for _, f in chunks]
    assume(not any(h.msgid in CRC_EXTRA and raw not in valid for h, raw in split(data).frames))  # see test_frames
    pipe, stats, _ = make(*MIXED, extra=[Beacon()] if beacon else None)
    now = time.monotonic()
    out = pipe.feed(data, DOWN, now)
    s = stats[DOWN]
    sent = split(b"".join(o.data for o in out)).frames
    assert s.frames_out == len(sent) == s.frames_in - s.dropped + s.injected
    assert s.bytes_out == sum(len(o.data) for o in out)
    assert s.delayed == sum(1 for o in out if o.release_s > now)
    # Every valid input frame that no rule drops is in the output, in order; untargeted ones byte for byte.
    kept = []
    for _, f in chunks:
        ((h, raw),) = split(f).frames
        if h.msgid == DISTANCE_SENSOR and not h.signed:
            sid = parse_all(raw)[0].id
            if sid == 1:
                continue
            if sid in (0, 2):
                kept.append(("targeted", sid))
                continue
        kept.append(("raw", raw))
    now_out = split(out[0].data).frames if out and out[0].release_s == now else []
    delayed = [split(o.data).frames[0] for o in out if o.release_s > now]

    def beacon_made(h: Any, raw: bytes) -> bool:  # an input may be a DISTANCE_SENSOR with id 99 too: it is kept
        return h.msgid == DISTANCE_SENSOR and raw not in valid and parse_all(raw)[0].id == 99

    seen = [(h, raw) for h, raw in now_out + delayed if not beacon_made(h, raw)]
    seen = [x for x in seen if x[0].msgid in CRC_EXTRA]  # garbage may yield unknown-id frames
    assert len(seen) == len(kept)
    # A source the beacon spoke for is renumbered after its frame (mitm_proxy/core/sequence.py): the frame is
    # the same but for its sequence number and CRC. Every other source's frames are byte for byte.
    raws = [raw for _, raw in seen] if not beacon else [_sans_seq(raw) for _, raw in seen]
    for kind, value in kept:
        if kind == "raw":
            assert (value if not beacon else _sans_seq(value)) in raws


def _sans_seq(raw: bytes) -> bytes:
    """A frame without its sequence number and CRC (v2: byte 4; v1: byte 2; a signature stays)."""
    at, end = (4, 10 + raw[1]) if raw[0] == 0xFD else (2, 6 + raw[1])
    return raw[:at] + raw[at + 1 : end] + raw[end + 2 :]


def test_a_readings_tap_sees_each_watched_reading_as_it_came_and_as_it_left() -> None:
    from mitm_proxy.core.readings import ReadingsTap

    pipe, _, _ = make(bias(sensor_id=3, offset_m=1.0),
                      {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 4}, "kind": "drop"})  # fmt: skip
    tap = ReadingsTap(1)
    pipe.attach(tap)
    now = time.monotonic()
    pipe.feed(pack(distance(cm=250, sensor_id=3)) + pack(distance(cm=300, sensor_id=5)), DOWN, now)  # slow path
    pipe.feed(pack(distance(cm=420, sensor_id=4)), DOWN, now)  # dropped by the attack
    pipe.feed(pack(local_position()) + pack(heartbeat()), DOWN, now)  # fast path: nothing targeted
    pipe.feed(pack(distance(cm=999, sensor_id=3)), UP, now)  # uplink: not a reading
    got = tap.take()
    assert got is not None and got["sysid"] == 1
    assert got["sensors"] == {
        "3": {"original_m": 2.5, "forwarded_m": 3.5, "flagged": False, "attacked_m": 3.5},
        "4": {"original_m": 4.2, "forwarded_m": None, "flagged": False},
        "5": {"original_m": 3.0, "forwarded_m": 3.0, "flagged": False},
    }
    pos = got["position"]
    assert pos["original_ned_m"] == pos["forwarded_ned_m"] and len(pos["original_ned_m"]) == 3
    assert tap.take() is None  # only what changed since


class Log:
    """An observer that writes down every hook call."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    def frames_in(self, direction: Direction, frames: Any) -> None:
        self.calls.append(("in", direction, len(frames)))

    def after_stage(self, stage: Any, pkts: Any) -> None:
        self.calls.append(("stage", stage.name, len(pkts)))

    def frame_out(self, direction: Direction, pos: int, header: Any, raw: bytes, data: bytes, pkt: Packet | None,
                  delay_s: float) -> None:  # fmt: skip
        self.calls.append(("out", pos, header.msgid, pkt is not None and pkt.changed, data is raw))

    def dropped(self, direction: Direction, pos: int, header: Any, raw: bytes, pkt: Packet) -> None:
        self.calls.append(("dropped", pos, header.msgid))


def test_observers_see_four_hooks_and_only_while_attached() -> None:
    pipe, _, _ = make(bias(sensor_id=3), {"target": {"message": "DISTANCE_SENSOR", "sensor_id": 4}, "kind": "drop"})
    log = Log()
    untargeted = pack(heartbeat())
    now = time.monotonic()
    assert pipe.feed(untargeted, DOWN, now)[0].data is untargeted and log.calls == []  # nobody watches: fast path
    pipe.attach(log)
    out = pipe.feed(untargeted, DOWN, now)
    assert out[0].data == untargeted  # the same bytes leave; the observer saw them
    assert log.calls == [("in", DOWN, 1), ("out", 0, HEARTBEAT, False, True)]
    log.calls.clear()
    pipe.feed(pack(heartbeat()) + pack(distance(sensor_id=3)) + pack(distance(sensor_id=4)), DOWN, now)
    assert log.calls == [
        ("in", DOWN, 3),
        ("out", 0, HEARTBEAT, False, True),
        ("stage", "attack", 1), ("out", 1, DISTANCE_SENSOR, True, False),  # rewritten by the bias
        ("stage", "attack", 0), ("dropped", 2, DISTANCE_SENSOR),  # dropped by the profile
    ]  # fmt: skip
    pipe.detach(log)
    log.calls.clear()
    assert pipe.feed(untargeted, DOWN, now)[0].data is untargeted and log.calls == []


def test_a_sender_that_prints_has_its_short_printable_runs_counted_as_text() -> None:
    """SITL's boot (measured): "Init ArduCopter ..." lines, then "*" progress marks and line tails between
    frames; the marks were garbage until the pipeline remembered that the sender prints."""
    pipe, stats, _ = make()
    down = stats.directions[Direction.DOWNLINK]
    frame = pack(heartbeat())
    pipe.feed(b"*" + frame, Direction.DOWNLINK, 0.0)
    assert down.bad == {"garbage": 1}  # nobody has printed yet: a lone printable byte is noise
    pipe.feed(b"Init ArduCopter V4.7.0-dev\n" + frame, Direction.DOWNLINK, 1.0)
    pipe.feed(b"*" + frame + b"*\n", Direction.DOWNLINK, 2.0)
    assert down.bad == {"garbage": 1, "text": 3}
    pipe.feed(b"*" + frame, Direction.DOWNLINK, 20.0)  # long after the last line
    assert down.bad == {"garbage": 2, "text": 3}

"""Field filters in the pipeline: a stage that wants a message only for a few sensor ids leaves the others alone.

An attack on DISTANCE_SENSOR sensor 3 does not want sensor 0's frames: they leave as they came (the very same
datagram object when nothing else in it is wanted), undecoded; sensor 3's are rewritten. A MAVLink 2 payload
truncated before the id byte reads sensor 0; a signed frame is wanted whole; a second stage that wants the
message whole, or narrows it on another field, lifts the filter; a profile swap moves it.
"""

from __future__ import annotations

import time
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline, _selected
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import (
    DISTANCE_SENSOR,
    distance,
    frames,
    heartbeat,
    mav,
    mavlink,
    pack,
    parse_all,
    signed_mav,
)
from tests.support.pipelines import bias, make, profile

DOWN = Direction.DOWNLINK


def filters_of(pipe: Pipeline) -> dict[int, tuple[int, frozenset[int]]]:
    """The field filters the pipeline gives the fast route (DISTANCE_SENSOR stays among the wanted ids)."""
    wanted = pipe.fast_wanted(DOWN)
    assert wanted is not None and DISTANCE_SENSOR in wanted[0]
    return wanted[1]


def bare(sensor_id: int, cm: int = 500) -> Any:
    """A DISTANCE_SENSOR whose bytes after the id are all zero: with the id 0 too, MAVLink 2 truncates the
    payload before the id byte."""
    return mavlink.MAVLink_distance_sensor_message(1000, 10, 4000, cm, 0, sensor_id, 0, 0)


def test_the_pipeline_narrows_to_the_targeted_sensors() -> None:
    pipe, _, _ = make(bias(sensor_id=3), bias(sensor_id=[5, 6]))
    assert filters_of(pipe) == {DISTANCE_SENSOR: (11, frozenset({3, 5, 6}))}
    pipe, _, _ = make(bias(sensor_id=3), {"target": {"message": "DISTANCE_SENSOR"}, "kind": "drop"})
    assert filters_of(pipe) == {}


def test_an_untargeted_sensor_passes_as_the_same_object_and_a_targeted_one_is_rewritten() -> None:
    pipe, stats, _ = make(bias(sensor_id=3, offset_m=2.0))
    m = mav()
    other = pack(heartbeat(), m) + pack(distance(cm=500, sensor_id=0), m)
    assert pipe.feed(other, DOWN, time.monotonic())[0].data is other
    d3, d1 = pack(distance(cm=500, sensor_id=3), m), pack(distance(cm=500, sensor_id=1), m)
    (out,) = pipe.feed(d1 + d3 + d1, DOWN, time.monotonic())
    msgs = parse_all(out.data)
    assert [x.current_distance for x in msgs] == [500, 700, 500]
    assert out.data.startswith(d1) and out.data.endswith(d1)
    assert stats[DOWN].rewritten == 1 and stats[DOWN].frames_out == 5


def test_a_truncated_payload_reads_sensor_0() -> None:
    m = mav()
    short = pack(bare(0), m)
    assert short[1] <= 11  # the id byte (payload offset 11) is not on the wire
    pipe, stats, _ = make(bias(sensor_id=0, offset_m=1.0))
    assert parse_all(pipe.feed(short, DOWN, time.monotonic())[0].data)[0].current_distance == 600
    pipe, stats, _ = make(bias(sensor_id=1, offset_m=1.0))
    assert pipe.feed(short, DOWN, time.monotonic())[0].data is short
    assert stats[DOWN].rewritten == 0


def test_a_signed_frame_of_a_filtered_id_is_wanted_whole() -> None:
    """Without the key the profile cannot touch signed frames; they are counted as it wanted them, any sensor."""
    pipe, stats, _ = make(bias(sensor_id=3))
    d0 = pack(distance(sensor_id=0), signed_mav())
    assert pipe.feed(d0, DOWN, time.monotonic())[0].data is d0
    assert stats[DOWN].signed_untouched == 1


class _Whole:
    """A stage that wants every DISTANCE_SENSOR (as the secure stage does), and counts them."""

    name = "whole"
    active = True
    message_ids = frozenset({DISTANCE_SENSOR})

    def __init__(self, filters: dict[int, tuple[str, frozenset[int]]] | None = None) -> None:
        self.seen: list[int] = []
        if filters is not None:
            self.field_filters = filters

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        self.seen.append(codec.decode(pkt)["id"])
        return [pkt]


def test_a_stage_that_wants_the_message_whole_lifts_the_filter() -> None:
    whole = _Whole()
    pipe, _, _ = make(bias(sensor_id=3), extra=[whole])
    assert filters_of(pipe) == {}
    pipe.feed(pack(distance(sensor_id=0)), DOWN, time.monotonic())
    assert whole.seen == [0]
    # Narrowed on another field (orientation, offset 12): no one byte decides for both.
    other = _Whole({DISTANCE_SENSOR: ("orientation", frozenset({25}))})
    pipe, _, _ = make(bias(sensor_id=3), extra=[other])
    assert filters_of(pipe) == {}
    # Narrowed on the same field: the union.
    same = _Whole({DISTANCE_SENSOR: ("id", frozenset({7}))})
    pipe, _, _ = make(bias(sensor_id=3), extra=[same])
    assert filters_of(pipe) == {DISTANCE_SENSOR: (11, frozenset({3, 7}))}
    pipe.feed(pack(distance(sensor_id=0)) + pack(distance(sensor_id=7)), DOWN, time.monotonic())
    assert same.seen == [7]


def test_a_profile_swap_moves_the_filter_between_two_datagrams() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(profile(bias(sensor_id=3, offset_m=1.0)))
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    d0, d3 = pack(distance(cm=500, sensor_id=0)), pack(distance(cm=500, sensor_id=3))
    assert pipe.feed(d0, DOWN, time.monotonic())[0].data is d0
    assert parse_all(pipe.feed(d3, DOWN, time.monotonic())[0].data)[0].current_distance == 600
    slot.offer(profile(bias(sensor_id=0, offset_m=1.0)))
    assert filters_of(pipe) == {DISTANCE_SENSOR: (11, frozenset({0}))}
    assert parse_all(pipe.feed(d0, DOWN, time.monotonic())[0].data)[0].current_distance == 600
    assert pipe.feed(d3, DOWN, time.monotonic())[0].data is d3


@given(frames(), st.sets(st.integers(0, 255), max_size=4))
def test_the_filter_reads_the_id_as_the_decoder_does(frame: bytes, values: set[int]) -> None:
    """Any frame pymavlink packs (v1, v2, signed, truncated): the byte the filter reads is the decoded field."""
    header, raw = split(frame).frames[0]
    if header.msgid != DISTANCE_SENSOR:
        return
    fields = codec.decode(Packet(raw, header, DOWN, 0, 0.0))
    assert _selected(header, raw, (11, frozenset(values))) == (fields["id"] in values)

"""Sequence numbers stay contiguous when the proxy adds or removes frames (mitm_proxy/core/sequence.py).

The property runs the real pipeline: a stage forges HEARTBEATs as system 1's autopilot on the clock
(``tick``), duplicates its LOCAL_POSITION_NED frames and drops its DISTANCE_SENSOR id 1, in any
interleaving with the real frames of three sources. What comes out is read by pymavlink (CRC-checked):
each source's numbers are contiguous, every frame that should be there is, and the sources nobody
forged for are byte for byte what came in.
"""

from __future__ import annotations

import itertools
import time

from hypothesis import given, settings
from hypothesis import strategies as st

from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.sequence import Sequencer
from mitm_proxy.core.stats import LinkStats
from tests.support.frames_support import (
    DISTANCE_SENSOR,
    LOCAL_POSITION_NED,
    distance,
    heartbeat,
    local_position,
    mav,
    pack,
    parse_all,
)

DOWN = Direction.DOWNLINK
A, B, C = (1, 1), (2, 1), (1, 2)  # A: forged for; B another system; C another component of system 1


def h(sysid: int, compid: int, seq: int) -> Header:
    return Header(2, 0, sysid, compid, seq, 9)


def test_a_forged_frame_takes_the_next_number_and_later_frames_follow() -> None:
    s = Sequencer()
    assert [s.real(h(1, 1, n)) for n in (254, 255)] == [254, 255]
    assert s.forged(1, 1, own=77) == 0  # wraps
    assert s.real(h(1, 1, 0)) == 1 and s.real(h(2, 1, 0)) == 0  # another source: untouched
    s.dropped(h(1, 1, 1))  # a dropped frame gives its number back
    assert s.real(h(1, 1, 2)) == 2


def test_forging_before_the_source_was_heard_starts_at_zero_and_the_source_follows_on() -> None:
    s = Sequencer()
    assert s.forged(255, 190, own=9) == 0 and s.forged(255, 190, own=9) == 1
    assert [s.real(h(255, 190, n)) for n in (130, 131)] == [2, 3]


class Forger:
    """A stage: forges HEARTBEATs as A on the clock, duplicates A's LOCAL_POSITION_NED, drops A's DISTANCE_SENSOR 1."""

    name = "forger"
    active = True
    message_ids = frozenset({LOCAL_POSITION_NED, DISTANCE_SENSOR})
    forges = frozenset({DOWN})

    def __init__(self) -> None:
        self.pending = 0

    def next_due_s(self) -> float | None:
        return 0.0 if self.pending else None

    def due(self, now_s: float, link: int) -> list[Packet]:
        fields = {"type": 2, "autopilot": 12, "base_mode": 0, "custom_mode": 0, "system_status": 4,
                  "mavlink_version": 3}  # fmt: skip
        out = [codec.build("HEARTBEAT", fields, sysid=A[0], compid=A[1], seq=123, direction=DOWN, link=link,
                           now_s=now_s) for _ in range(self.pending)]  # fmt: skip
        self.pending = 0
        return out

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        if (pkt.header.sysid, pkt.header.compid) != A:
            return [pkt]
        if pkt.header.msgid == DISTANCE_SENSOR:
            return [] if codec.decode(pkt)["id"] == 1 else [pkt]
        copy = Packet(pkt.raw, pkt.header, pkt.direction, pkt.link, now_s, injected=True, origin="duplicate")
        return [pkt, copy]


MESSAGES = {"hb": heartbeat, "pos": local_position, "d0": lambda: distance(sensor_id=0),
            "d1": lambda: distance(sensor_id=1)}  # fmt: skip
real = st.tuples(st.just("real"), st.sampled_from([A, B, C]), st.sampled_from(sorted(MESSAGES)), st.booleans())
events = st.lists(st.one_of(real, st.tuples(st.just("forge"), st.integers(1, 3))), max_size=60)


@settings(max_examples=150, deadline=None)
@given(events, st.integers(0, 255), st.booleans())
def test_any_interleaving_of_real_and_forged_frames_leaves_every_stream_contiguous(
    script: list[tuple], first_seq: int, seen_first: bool
) -> None:
    stage = Forger()
    stats = LinkStats(1)
    pipe = Pipeline(0, [stage], stats=stats)
    pipe.next_tick_s()  # what the link does at start: the forged direction is watched from now on
    senders = {src: mav(*src, seq=first_seq) for src in (A, B, C)}
    out: list[bytes] = []
    sent: dict[tuple[int, int], list[bytes]] = {A: [], B: [], C: []}
    expected_a = added = 0
    pending: list[bytes] = []  # real frames of the datagram being built
    if seen_first:  # the forged-for source was heard before the first forgery
        script = [("real", A, "hb", False), *script]

    def flush() -> None:
        if pending:
            out.extend(o.data for o in pipe.feed(b"".join(pending), DOWN, time.monotonic()))
            pending.clear()

    for ev in script:
        if ev[0] == "forge":
            flush()
            stage.pending = ev[1]
            expected_a += ev[1]
            added += ev[1]
            out.extend(o.data for _d, o in pipe.tick(time.monotonic()))
            continue
        _, src, kind, same_datagram = ev
        if not same_datagram:
            flush()
        frame = pack(MESSAGES[kind](), senders[src])
        sent[src].append(frame)
        pending.append(frame)
        if src == A:
            expected_a += {"pos": 2, "d1": 0}.get(kind, 1)
            added += kind == "pos"  # its copy
    flush()
    got: dict[tuple[int, int], list[bytes]] = {A: [], B: [], C: []}
    for data in out:
        for hd, raw in split(data).frames:
            got[(hd.sysid, hd.compid)].append(raw)
    msgs = parse_all(b"".join(out))  # pymavlink's parser: every CRC checks
    assert len(msgs) == sum(len(v) for v in got.values()) and all(m.get_type() != "BAD_DATA" for m in msgs)
    assert got[B] == sent[B] and got[C] == sent[C]  # nobody forged for them: byte for byte
    assert len(got[A]) == expected_a
    seqs = [split(raw).frames[0][0].seq for raw in got[A]]
    assert all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(seqs)), seqs
    if seen_first and seqs:
        assert seqs[0] == first_seq  # the stream goes on from the sender's own numbers
    assert stats[DOWN].injected == added and stats[DOWN].duplicated == sum(
        1 for f in sent[A] if parse_all(f)[0].get_type() == "LOCAL_POSITION_NED")

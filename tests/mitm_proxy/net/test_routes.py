"""Per-endpoint rules as a pure library: parsing from URL options, and what a gate lets through."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from mavframe.frames import StreamFramer, split
from mavframe.packet import Direction
from mitm_proxy.net.rules import EndpointGate, EndpointRules, FrameFilter, rules_from_options
from secuav_common.loading import InputError
from secuav_common.urls import parse_endpoint


def _frames(sysid: int, compid: int = 1) -> dict[str, bytes]:
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    return {
        "HEARTBEAT": mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav),
        "DISTANCE_SENSOR": mav.distance_sensor_encode(1000, 10, 4000, 250, 0, 1, 0, 0).pack(mav),
        "ATTITUDE": mav.attitude_encode(1000, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav),
        "COMMAND_LONG": mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
    }


def test_url_options_become_typed_rules() -> None:
    ep = parse_endpoint("udpout://127.0.0.1:14550?deny=DISTANCE_SENSOR,30&allow_up=HEARTBEAT&deny_sysid_up=7")
    rules = rules_from_options(ep)
    assert rules.down.deny == ["DISTANCE_SENSOR", "30"]
    assert rules.up.allow == ["HEARTBEAT"] and rules.up.deny_sysid == [7]
    assert not rules.listen_only and not rules.empty
    assert rules_from_options(parse_endpoint("tcpin://127.0.0.1:5760?listen_only=true")).listen_only
    assert rules_from_options(parse_endpoint("udpin://127.0.0.1:1")).empty


@pytest.mark.parametrize(
    ("url", "needle"),
    [
        ("udpout://127.0.0.1:1?deny=NOT_A_MESSAGE", "'NOT_A_MESSAGE' is not a MAVLink message name"),
        ("udpout://127.0.0.1:1?deny=99999", "message id 99999"),
        ("udpout://127.0.0.1:1?deny_sysid=300", "300 is not a MAVLink id"),
        ("udpout://127.0.0.1:1?deny_sysid=x", "deny_sysid"),
        ("udpout://127.0.0.1:1?listen_only=maybe", "listen_only"),
        ("udpout://127.0.0.1:1?block=HEARTBEAT", "option block: unknown option"),
    ],
)
def test_a_bad_rule_is_one_error_naming_the_option(url: str, needle: str) -> None:
    with pytest.raises(InputError) as err:
        rules_from_options(parse_endpoint(url), "flags")
    text = str(err.value)
    assert needle in text and "flags" in text and "\n" not in text


def test_a_gate_drops_by_message_sysid_and_compid_and_counts_the_rule() -> None:
    f1, f2 = _frames(1), _frames(2, compid=191)
    rules = EndpointRules(
        down=FrameFilter(deny=["DISTANCE_SENSOR"], deny_sysid=[2]),
        up=FrameFilter(allow=["HEARTBEAT", 76], allow_compid=[191]),
    )
    gate = EndpointGate(rules)
    datagram = f1["HEARTBEAT"] + f1["DISTANCE_SENSOR"] + f2["ATTITUDE"] + f1["ATTITUDE"]
    assert gate.apply(datagram, Direction.DOWNLINK) == f1["HEARTBEAT"] + f1["ATTITUDE"]
    assert gate.dropped == {"down.deny": 1, "down.deny_sysid": 1}
    uplink = f2["HEARTBEAT"] + f2["COMMAND_LONG"] + f1["HEARTBEAT"]
    assert gate.apply(uplink, Direction.UPLINK) == f2["HEARTBEAT"] + f2["COMMAND_LONG"]
    assert gate.dropped["up.allow_compid"] == 1
    whole = f1["HEARTBEAT"] + f1["ATTITUDE"]
    assert gate.apply(whole, Direction.DOWNLINK) is whole  # nothing dropped: the same bytes go on


def test_a_filtered_datagram_drops_what_is_not_a_frame() -> None:
    """Bytes crafted so a lax walker would see a harmless frame must not carry a denied one past the filter."""
    f = _frames(1)
    gate = EndpointGate(EndpointRules(up=FrameFilter(deny=["COMMAND_LONG"])))
    fake = bytes([0xFD, 40, 0, 0, 0, 1, 1, 0, 0, 0])  # a v2 header claiming a 40-byte HEARTBEAT that is not there
    assert gate.apply(fake + f["COMMAND_LONG"] + f["HEARTBEAT"], Direction.UPLINK) == f["HEARTBEAT"]


_NAMES = ["HEARTBEAT", "DISTANCE_SENSOR", "ATTITUDE", "COMMAND_LONG"]


@given(
    st.lists(st.tuples(st.sampled_from(_NAMES), st.integers(1, 3), st.sampled_from([1, 191])), max_size=12),
    st.lists(st.sampled_from(_NAMES), max_size=2),
    st.lists(st.integers(1, 3), max_size=2),
    st.lists(st.sampled_from([1, 191]), max_size=1),
)
def test_a_gate_keeps_exactly_the_frames_its_rules_allow(
    stream: list[tuple[str, int, int]], deny: list[str], allow_sysid: list[int], deny_compid: list[int]
) -> None:
    frames = [(_frames(s, c)[name], name, s, c) for name, s, c in stream]
    gate = EndpointGate(EndpointRules(down=FrameFilter(deny=deny, allow_sysid=allow_sysid, deny_compid=deny_compid)))
    out = gate.apply(b"".join(f for f, *_ in frames), Direction.DOWNLINK)
    want = [f for f, name, s, c in frames
            if name not in deny and (not allow_sysid or s in allow_sysid) and c not in deny_compid]  # fmt: skip
    assert [raw for _h, raw in split(out).frames] == want
    assert sum(gate.dropped.values()) == len(frames) - len(want)


@given(
    st.lists(st.one_of(st.sampled_from(_NAMES), st.binary(min_size=1, max_size=12)), max_size=10),
    st.lists(st.integers(1, 40), min_size=1, max_size=30),
)
def test_a_stream_cut_anywhere_yields_the_frames_of_the_whole(parts: list[str | bytes], cuts: list[int]) -> None:
    f = _frames(1)
    stream = b"".join(f[p] if isinstance(p, str) else p for p in parts)
    framer = StreamFramer()
    got: list[bytes] = []
    i = 0
    for size in cuts * (len(stream) // max(1, sum(cuts)) + 1):
        if i >= len(stream):
            break
        chunk = framer.feed(stream[i : i + size])
        got.extend(raw for _h, raw in split(chunk).frames)
        i += size
    tail = b"\x00" * 600  # enough bytes behind anything held to show what it was
    got.extend(raw for _h, raw in split(framer.feed(tail)).frames)
    assert framer.held == 0
    assert got == [raw for _h, raw in split(stream + tail).frames]

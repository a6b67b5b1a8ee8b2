"""The pure parts of the SITL checks (scripts/sitl/sitl_check.py): reading a frame's header from its
bytes, which the byte-exact forwarding figure and the rates table rest on, and the autopilot's
version as ArduPilot and PX4 each encode it in AUTOPILOT_VERSION. The checks themselves need the
SITL binaries and are not run here (docs/ardupilot.md, docs/px4.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav2
from pymavlink.dialects.v20 import development

from tests.support.sitl_scripts import load_script

sitl_check = load_script("sitl_check")
check_ardupilot = load_script("check_ardupilot")
check_px4 = load_script("check_px4")


class _Out:
    """A pymavlink encoder with a chosen header."""

    def __init__(self, module: Any, sysid: int, compid: int, seq: int) -> None:
        self.mav = module.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.seq = seq

    def pack(self, msg: Any) -> bytes:
        return bytes(msg.pack(self.mav))


@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 65535))
def test_frame_header_reads_mavlink2_frames_as_pymavlink_packs_them(sysid: int, compid: int, seq: int,
                                                                    distance_cm: int) -> None:
    frame = _Out(mav2, sysid, compid, seq).pack(
        mav2.MAVLink_distance_sensor_message(1, 0, 4000, distance_cm, 0, 0, 25, 0))
    assert sitl_check.frame_header(frame) == (sysid, compid, 132, seq)


@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255))
def test_frame_header_reads_mavlink1_frames(sysid: int, compid: int, seq: int) -> None:
    frame = _Out(mav1, sysid, compid, seq).pack(mav1.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    assert sitl_check.frame_header(frame) == (sysid, compid, 0, seq)


@given(st.binary(max_size=12))
def test_frame_header_is_none_for_what_is_not_a_frame_start(data: bytes) -> None:
    if (len(data) >= 10 and data[0] == 0xFD) or (len(data) >= 6 and data[0] == 0xFE):
        return
    assert sitl_check.frame_header(data) is None


def test_key_of_a_message_the_dialect_does_not_define_comes_from_its_frame() -> None:
    # PX4 sends GNSS_INTEGRITY (#441, development.xml); ardupilotmega, the checks' dialect, lacks it,
    # and pymavlink gives such a message a header of zeros, so both sides of the forwarding
    # comparison silently dropped it before the key was read from the frame
    frame = _Out(development, 1, 1, 77).pack(
        development.MAVLink_gnss_integrity_message(4, 0, 0, 0, 0, 0, 65535, 65535, 255, 255, 255, 255))
    parsed = mav2.MAVLink(None).parse_buffer(frame)
    assert parsed is not None and len(parsed) == 1
    m = parsed[0]
    assert m.get_type() == "UNKNOWN_441"
    assert sitl_check.key(m) == (1, 1, 441, 77)


def test_key_of_a_known_message_agrees_with_pymavlink() -> None:
    frame = _Out(mav2, 3, 1, 9).pack(mav2.MAVLink_rangefinder_message(12.5, 0.0))
    m = mav2.MAVLink(None).parse_buffer(frame)[0]
    assert sitl_check.key(m) == (m.get_srcSystem(), m.get_srcComponent(), m.get_msgId(), m.get_seq()) == (3, 1, 173, 9)


def test_version_text_of_arducopter() -> None:
    # ArduPilot: V4.7.0-dev, FIRMWARE_VERSION_TYPE_DEV, its git hash's first 8 characters as text
    sw = (4 << 24) | (7 << 16) | (0 << 8) | 0
    assert sitl_check.version_text(sw, b"2598e9d4") == "4.7.0-dev (git 2598e9d4)"


def test_version_text_of_px4() -> None:
    # PX4 v1.17.0-1-g5b73eed759: the hash's first 16 hex digits as a little-endian uint64
    sw = (1 << 24) | (17 << 16) | (0 << 8) | 0
    custom = (0x5B73EED7591F60D1).to_bytes(8, "little")
    assert sitl_check.version_text(sw, custom) == "1.17.0-dev (git 5b73eed7)"


def test_version_text_of_a_release_and_of_an_unknown_type() -> None:
    assert sitl_check.version_text((1 << 24) | (14 << 16) | 255, bytes(8)) == "1.14.0 (git 00000000)"
    assert sitl_check.version_text((1 << 24) | (14 << 16) | 7, bytes(8)) == "1.14.0 (type 7) (git 00000000)"


def test_in_order_of_an_exact_copy_and_of_one_cut_at_the_end() -> None:
    sent = [bytes([i]) for i in range(10)]
    assert sitl_check.in_order(sent, sent) == sitl_check.InOrder(10, 0, 0, 0, None)
    assert sitl_check.in_order(sent, sent[:7]) == sitl_check.InOrder(7, 0, 0, 3, None)


def test_in_order_tells_a_lost_frame_from_an_altered_or_reordered_one() -> None:
    sent = [bytes([i]) for i in range(10)]
    # one lost in the middle: the rest still match (a position-by-position comparison called all of
    # them different, which is how a dropped datagram at the ground station looked like a bad proxy)
    assert sitl_check.in_order(sent, sent[:4] + sent[5:]) == sitl_check.InOrder(9, 0, 1, 0, None)
    altered = [*sent[:3], b"x", *sent[4:]]
    assert sitl_check.in_order(sent, altered) == sitl_check.InOrder(9, 1, 1, 0, 3)
    swapped = [*sent[:3], sent[4], sent[3], *sent[5:]]
    got = sitl_check.in_order(sent, swapped)
    assert got.unmatched == 1 and got.first_unmatched == 4 and got.matched == 9


@given(st.lists(st.binary(min_size=1, max_size=3), max_size=40), st.data())
def test_in_order_of_any_subsequence_matches_all_of_it(sent: list[bytes], data: st.DataObject) -> None:
    keep = data.draw(st.lists(st.booleans(), min_size=len(sent), max_size=len(sent)))
    received = [f for f, k in zip(sent, keep, strict=True) if k]
    got = sitl_check.in_order(sent, received)
    assert got.matched == len(received) and got.unmatched == 0
    assert got.missing + got.tail == len(sent) - len(received)


def test_udp_drops_reads_the_socket_of_that_port() -> None:
    table = (
        "   sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode ref "
        "pointer drops\n"
        "  123: 0100007F:D7F0 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 1 2 "
        "0000000000000000 17\n"
        "  124: 0100007F:3902 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 3 2 "
        "0000000000000000 0\n"
    )
    assert sitl_check.udp_drops(0xD7F0, table) == 17
    assert sitl_check.udp_drops(14594, table) == 0
    assert sitl_check.udp_drops(14550, table) is None


def _parsed(msg: Any) -> Any:
    return mav2.MAVLink(None).parse_buffer(_Out(mav2, 1, 1, 0).pack(msg))[0]


def test_each_autopilot_names_the_messages_that_carry_its_rangefinders() -> None:
    ardupilot = check_ardupilot.ArduCopter(Path("/nonexistent"))
    px4 = check_px4.PX4(Path("/nonexistent"), 3)
    ds = {i: _parsed(mav2.MAVLink_distance_sensor_message(1, 20, 4000, 1234, 0, i, 25, 0)) for i in range(4)}
    rf = _parsed(mav2.MAVLink_rangefinder_message(12.5, 0.0))  # exact in float32
    # ArduPilot: ids 0-2 of rangefinders.parm, and RANGEFINDER (#173) for the first downward one
    assert [ardupilot.carriers(ds[i]) for i in range(4)] == [[(0, 12.34)], [(1, 12.34)], [(2, 12.34)], []]
    assert ardupilot.carriers(rf) == [(0, 12.5)]
    # PX4 SIH: its one downward sensor, id 0; PX4 does not send RANGEFINDER
    assert [px4.carriers(ds[i]) for i in range(2)] == [[(0, 12.34)], []]
    assert px4.carriers(rf) == []
    assert len(ardupilot.offsets_m) == 3 and len(px4.offsets_m) == 1


# --- the checks of a run: each judges what the run measured and returns the rows it prints --------------------


def _compare(**over: Any) -> dict[str, Any]:
    """A :func:`sitl_check.compare` result of a run where everything held; ``over`` changes parts of it."""
    base: dict[str, Any] = {
        "downlink_frames": 120, "received": 118, "unmatched": 0, "untargeted_orig": 100, "untargeted_got": 98,
        "order": sitl_check.InOrder(98, 0, 0, 2, None), "twin_example": None, "clearance": [],
        "per": {("DISTANCE_SENSOR", 0): {"frames": 20, "changed": 20, "delta_m": [5.0] * 20, "no_reading": 3}},
        "no_reading": {"frames": 3, "made_valid": 0},
    }
    return base | over


def test_a_vehicle_that_never_reached_its_height_fails_its_flight_row() -> None:
    flown = {"mode": "MAV_RESULT_ACCEPTED", "takeoff": "MAV_RESULT_ACCEPTED", "takeoff_after_s": 4.1,
             "reached_m": 9.6, "climb_s": 8.0, "land": "MAV_RESULT_ACCEPTED", "landed_disarmed_s": 14.2}
    rows = sitl_check.check_flight({1: flown, 2: flown | {"reached_m": None}}, "GUIDED")
    assert [r.ok for r in rows] == [True, False]
    assert rows[0].text.startswith("GUIDED flight, sysid 1: ") and not rows[0].text.endswith("FAIL")
    assert rows[1].text.endswith("  FAIL")


def test_an_empty_parameter_list_and_a_short_one_fail() -> None:
    rows = sitl_check.check_parameters({1: (1200, 1200, 3.2), 2: (0, 0, 1.0), 3: (1199, 1200, 9.9)})
    assert [r.ok for r in rows] == [True, False, False]
    assert rows[0].text == "parameters, sysid 1, through the proxy: 1200 of 1200 in 3.2 s"


def test_a_mission_holds_only_when_accepted_and_read_back_whole() -> None:
    assert sitl_check.check_mission(3, 3, "MAV_MISSION_ACCEPTED")[0].ok
    assert not sitl_check.check_mission(3, 2, "MAV_MISSION_ACCEPTED")[0].ok
    assert not sitl_check.check_mission(3, 3, "MAV_MISSION_ERROR")[0].ok


def test_forwarding_fails_on_an_altered_frame_or_a_long_tail_not_on_a_lost_one() -> None:
    assert sitl_check.check_forwarding(1, _compare())[0].ok
    lost = sitl_check.check_forwarding(1, _compare(order=sitl_check.InOrder(95, 0, 3, 2, None)))[0]
    assert lost.ok and "3 lost on the way" in lost.text  # judged against the kernel's drops by check_losses
    altered = sitl_check.check_forwarding(1, _compare(order=sitl_check.InOrder(97, 1, 0, 2, 40)))[0]
    assert not altered.ok and "FAIL, 1 altered or out of order, the first at 40" in altered.text
    assert not sitl_check.check_forwarding(1, _compare(order=sitl_check.InOrder(78, 0, 0, 22, None)))[0].ok


def test_a_reading_left_as_it_was_fails_the_attack_and_is_named() -> None:
    rows = sitl_check.check_attack(_compare(), (5.0,))
    assert all(r.ok for r in rows) and rows[-1].text.endswith("changed: yes")
    per = {("DISTANCE_SENSOR", 0): {"frames": 20, "changed": 20, "delta_m": [5.0] * 20, "no_reading": 0},
           ("RANGEFINDER", 0): {"frames": 20, "changed": 0, "delta_m": [], "no_reading": 0}}
    rows = sitl_check.check_attack(_compare(per=per, twin_example=(17.5, 12.5)), (5.0,))
    assert [r.ok for r in rows] == [True, False, True, True]
    assert "TRUE VALUE LEFT ON THE WIRE" in rows[1].text
    assert rows[2].text.endswith("DISTANCE_SENSOR id 0 = 17.50 m beside RANGEFINDER = 12.50 m")
    assert rows[3].text.endswith("changed: NO")


def test_a_clearance_that_reveals_the_truth_holds_only_if_the_proxy_said_so() -> None:
    revealing = _compare(clearance=[(12.4, 12.5, 17.5)] * 5)  # (bottom_clearance, true, attacked)
    said = "2026-11-27 WARNING attack.true_copy sysid=1 carriers=ALTITUDE.bottom_clearance"
    silent = sitl_check.check_clearance(1, revealing, ["proxy.stats sysid=1 bad=0"])
    assert "REVEALS THE TRUE DISTANCE" in silent[0].text and [r.ok for r in silent] == [True, False]
    assert [r.ok for r in sitl_check.check_clearance(1, revealing, [said])] == [True, True]
    following = sitl_check.check_clearance(1, _compare(clearance=[(17.4, 12.5, 17.5)] * 5), [])
    assert len(following) == 1 and following[0].ok
    assert sitl_check.check_clearance(1, _compare(), []) == []


def test_a_no_reading_made_valid_by_the_bias_fails() -> None:
    assert sitl_check.check_no_reading(_compare())[0].ok
    assert not sitl_check.check_no_reading(_compare(no_reading={"frames": 3, "made_valid": 1}))[0].ok


def test_frames_lost_are_accounted_for_only_by_the_kernels_drops() -> None:
    assert sitl_check.check_losses(0, 0, "udp") == []
    assert sitl_check.check_losses(4, 6, "udp")[0].ok
    assert not sitl_check.check_losses(7, 6, "udp")[0].ok
    tcp = sitl_check.check_losses(1, None, "tcpin")[0]  # TCP loses nothing, so one lost frame is the proxy's
    assert not tcp.ok and "a tcpin link (nothing may be lost)" in tcp.text


def test_the_rates_table_and_the_stats_lines_inform_without_judging() -> None:
    rows = sitl_check.check_rates({"ATTITUDE": 10.0, "RANGEFINDER": 5.0}, {"ATTITUDE": 10.0, "SIMSTATE": 2.0}, 30)
    assert all(r.ok for r in rows) and len(rows) == 5
    assert "only through the proxy: ['RANGEFINDER']; only direct: ['SIMSTATE']" in rows[0].text
    log = ["... INFO proxy.stats sysid=1 frames=10 bad=2", "... INFO proxy.stats sysid=2 frames=9 bad=0"]
    stats = sitl_check.proxy_stats(log, [1, 2, 3])
    assert all(r.ok for r in stats) and [r.text for r in stats][1] == "  bad=2 on a healthy link" and len(stats) == 3
    assert not sitl_check.check_ground_frames(1)[0].ok and sitl_check.check_ground_frames(0)[0].ok

"""pymavlink as a ground station against the running simulator: what MAVProxy and QGC rely on.

The simulator ticks at 1x in the event loop; the GCS (blocking mavutil) runs in
a worker thread, as a separate program would. Truth and link counters are read
from the in-process runner.
"""

from __future__ import annotations

import asyncio
import math
import random
import struct
import time
from collections.abc import Callable

import pytest
from pymavlink import mavutil

from flightsim.mavlink.parameters import int_to_wire, wire_to_int
from flightsim.runner import SimRunner
from flightsim.vehicle import Vehicle
from tests.support.gcs import Gcs
from tests.support.live_sim import live_sim

mav = mavutil.mavlink
ACCEPTED, TEMP_REJECTED, DENIED, UNSUPPORTED = 0, 1, 2, 3


async def _run(port: int, scenario: str, body: Callable[[SimRunner, Gcs], None]) -> None:
    gcs = Gcs(port)  # bound before the vehicle starts sending
    try:
        async with live_sim(scenario, [port]) as runner:
            await asyncio.to_thread(body, runner, gcs)
    finally:
        gcs.close()


def _vehicle(runner: SimRunner, sysid: int = 1) -> Vehicle:
    return runner.sim.vehicles[sysid]


def _take_off(gcs: Gcs) -> None:
    assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
    assert gcs.command(mav.MAV_CMD_NAV_TAKEOFF) == ACCEPTED  # all NaN: MIS_TAKEOFF_ALT
    gcs.wait_mode("LOITER", 12)


def _count(gcs: Gcs, kind: str, seconds: float) -> int:
    gcs.drain()
    n = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        m = gcs.conn.recv_match(type=kind, blocking=True, timeout=0.1)
        if m is not None and m.get_srcSystem() == 1:
            n += 1
    return n


# -- parameters ------------------------------------------------------------------------------
def _parameters(runner: SimRunner, gcs: Gcs) -> None:
    v = _vehicle(runner)
    table = {p.name: p for p in v.params()}
    gcs.recv("HEARTBEAT")
    gcs.mav.param_request_list_send(1, 1)
    got: dict[int, object] = {}
    count = None
    while count is None or len(got) < count:
        pv = gcs.recv("PARAM_VALUE", 3.0)
        count = pv.param_count
        got[pv.param_index] = pv
    assert count == len(table)
    assert sorted(got) == list(range(count))
    names = {pv.param_id: pv for pv in got.values()}
    assert set(names) == set(table)
    for name, p in table.items():
        pv = names[name]
        if p.is_int:  # bytewise, as PX4 sends it
            assert pv.param_type == mav.MAV_PARAM_TYPE_INT32
            assert wire_to_int(pv.param_value) == int(p.value), name
        else:
            assert pv.param_type == mav.MAV_PARAM_TYPE_REAL32
            assert pv.param_value == pytest.approx(p.value, rel=1e-6), name

    # float set -> echo, read back, applied
    gcs.mav.param_set_send(1, 1, b"MPC_XY_CRUISE", 3.25, mav.MAV_PARAM_TYPE_REAL32)
    echo = gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "MPC_XY_CRUISE")
    assert echo.param_value == pytest.approx(3.25)
    gcs.mav.param_request_read_send(1, 1, b"MPC_XY_CRUISE", -1)
    assert gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "MPC_XY_CRUISE").param_value == pytest.approx(3.25)
    assert v.get_param("MPC_XY_CRUISE").value == pytest.approx(3.25)

    # int set, bytewise as QGC/MAVSDK do; read by index
    gcs.mav.param_set_send(1, 1, b"MPC_YAW_MODE", int_to_wire(3), mav.MAV_PARAM_TYPE_INT32)
    echo = gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "MPC_YAW_MODE")
    assert wire_to_int(echo.param_value) == 3
    gcs.mav.param_request_read_send(1, 1, b"", echo.param_index)
    again = gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_index == echo.param_index)
    assert again.param_id == "MPC_YAW_MODE" and wire_to_int(again.param_value) == 3

    # out of range: refused, answered with the unchanged value and a reason
    gcs.mav.param_set_send(1, 1, b"MPC_XY_CRUISE", 1e6, mav.MAV_PARAM_TYPE_REAL32)
    echo = gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "MPC_XY_CRUISE")
    assert echo.param_value == pytest.approx(3.25)
    assert "rejected" in gcs.expect_text("MPC_XY_CRUISE")


@pytest.mark.timeout(60)
async def test_parameter_list_is_complete_and_set_read_round_trip(udp_port: Callable[[], int]) -> None:
    await _run(udp_port(), "anchors8", _parameters)


# -- modes, commands, streams, garbage, reposition, RTL ---------------------------------------
def _bad_crc(frame: bytes) -> bytes:
    return frame[:-2] + bytes([frame[-2] ^ 0x55, frame[-1]])


def _flight(runner: SimRunner, gcs: Gcs) -> None:
    v = _vehicle(runner)
    hb = gcs.recv("HEARTBEAT")
    assert (hb.type, hb.autopilot) == (mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4)
    assert mavutil.mode_string_v10(hb) == "MANUAL"
    assert hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED == 0

    # unknown command: answered, never silence
    assert gcs.command(mav.MAV_CMD_USER_1) == UNSUPPORTED
    assert gcs.command(65000) == UNSUPPORTED  # an id no dialect assigns

    # arming when not ready: in Land mode the commander refuses, with the reason as STATUSTEXT
    assert gcs.set_px4_mode("LAND") == ACCEPTED
    assert gcs.heartbeat_mode() == "LAND"
    assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == DENIED
    gcs.expect_text("Arming denied")
    assert not v.armed
    # Mission without a mission, Offboard without setpoints: temporarily rejected as PX4 does
    assert gcs.set_px4_mode("MISSION") == TEMP_REJECTED
    assert gcs.set_px4_mode("OFFBOARD") == TEMP_REJECTED
    assert gcs.set_px4_mode("POSCTL") == ACCEPTED
    gcs.wait_mode("POSCTL", 2)

    # a stream rate follows SET_MESSAGE_INTERVAL (20 Hz default -> 5 Hz)
    assert _count(gcs, "ATTITUDE", 1.0) >= 16
    assert gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, 200_000) == ACCEPTED
    assert 3 <= _count(gcs, "ATTITUDE", 1.0) <= 7
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_GET_MESSAGE_INTERVAL, 0, mav.MAVLINK_MSG_ID_ATTITUDE, 0, 0, 0, 0, 0, 0)
    mi = gcs.recv("MESSAGE_INTERVAL", 2.0, lambda m: m.message_id == mav.MAVLINK_MSG_ID_ATTITUDE)
    assert mi.interval_us == 200_000
    assert gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, 0) == ACCEPTED  # default

    # arm, take off: the modes on the wire read as PX4's
    assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
    assert gcs.command(mav.MAV_CMD_NAV_TAKEOFF) == ACCEPTED
    assert gcs.heartbeat_mode() == "TAKEOFF"
    gcs.wait_mode("LOITER", 12)
    hb = gcs.recv("HEARTBEAT")
    assert hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == mav.MAV_STATE_ACTIVE
    time.sleep(1.0)
    assert abs(-v.truth.pos_ned_m[2] - 2.5) < 0.2

    # malformed datagrams are counted and ignored; the vehicle keeps hovering
    stats = runner.vehicles[0].personality.stats
    before = stats.rx_malformed
    unknown = gcs.mav.command_long_encode(1, 1, mav.MAV_CMD_USER_2, 0, 0, 0, 0, 0, 0, 0, 0)
    good = unknown.pack(gcs.mav)
    rng = random.Random(7)
    bad = [
        bytes(rng.randrange(256) for _ in range(64)),  # garbage
        good[: len(good) // 2],  # truncated
        _bad_crc(good),  # bad CRC
        b"\xfd\xff" + bytes(10),  # a header that claims more than the datagram holds
        struct.pack("<B", 0xFE) * 40,  # v1 magic bytes and nothing else
    ]
    alt_before = -v.truth.pos_ned_m[2]
    for datagram in bad * 20:
        gcs.conn.write(datagram)
    # a valid frame after garbage in the same datagram is still found and answered
    gcs.conn.write(bytes(rng.randrange(256) for _ in range(23)) + good)
    assert gcs.recv("COMMAND_ACK", 2.0, lambda m: m.command == mav.MAV_CMD_USER_2).result == UNSUPPORTED
    time.sleep(0.5)
    assert stats.rx_malformed - before == len(bad) * 20 + 1
    assert gcs.heartbeat_mode() == "LOITER"
    assert v.armed and not v.crashed
    assert abs(-v.truth.pos_ned_m[2] - alt_before) < 0.15

    # DO_REPOSITION (COMMAND_INT, as MAVSDK goto_location): fly there and hold
    from secuav_common.geo import ned_to_geodetic

    start = v.truth.pos_ned_m
    lat, lon, _ = ned_to_geodetic(v.home, start[0] + 1.0, start[1] - 1.0, 0.0)
    gcs.mav.command_int_send(
        1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0,
        -1, 0, 0, math.nan, round(lat * 1e7), round(lon * 1e7), 3.0,
    )  # fmt: skip
    ack = gcs.recv("COMMAND_ACK", 2.0, lambda m: m.command == mav.MAV_CMD_DO_REPOSITION)
    assert ack.result == ACCEPTED
    deadline = time.monotonic() + 8
    while math.dist(v.truth.pos_ned_m, (start[0] + 1.0, start[1] - 1.0, -3.0)) > 0.2:
        assert time.monotonic() < deadline, v.truth.pos_ned_m
        time.sleep(0.1)
    assert gcs.heartbeat_mode() == "LOITER"

    # RTL: climb to RTL_RETURN_ALT (set over the link), fly home (the scenario origin), land, disarm
    gcs.mav.param_set_send(1, 1, b"RTL_RETURN_ALT", 3.5, mav.MAV_PARAM_TYPE_REAL32)
    gcs.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "RTL_RETURN_ALT")
    assert gcs.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH) == ACCEPTED
    assert gcs.heartbeat_mode() == "RTL"
    peak = 0.0
    deadline = time.monotonic() + 30
    while v.armed:
        assert time.monotonic() < deadline, v.truth.pos_ned_m
        peak = max(peak, -v.truth.pos_ned_m[2])
        time.sleep(0.05)
    end = v.truth.pos_ned_m
    assert 3.3 < peak < 3.8
    assert math.hypot(end[0], end[1]) < 0.5 and -end[2] < 0.1
    assert not v.crashed
    gcs.recv("EXTENDED_SYS_STATE", 2.0, lambda m: m.landed_state == mav.MAV_LANDED_STATE_ON_GROUND)


@pytest.mark.slow
@pytest.mark.timeout(90)
async def test_gcs_modes_commands_streams_garbage_reposition_and_rtl(udp_port: Callable[[], int]) -> None:
    await _run(udp_port(), "anchors8", _flight)


# -- offboard loss -------------------------------------------------------------------------------
def _offboard_loss(runner: SimRunner, gcs: Gcs) -> None:
    v = _vehicle(runner)
    gcs.recv("HEARTBEAT")
    _take_off(gcs)
    # attitude setpoints (MAVSDK set_attitude) are refused out loud and do not count as a stream
    gcs.mav.set_attitude_target_send(0, 1, 1, 0b0000_0111, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0.5)
    assert "not supported" in gcs.expect_text("attitude setpoints")
    assert gcs.set_px4_mode("OFFBOARD") == TEMP_REJECTED
    here = v.estimate.pos_ned_m
    pos_yaw = 2552  # ignore velocity, acceleration and yaw rate: MAVSDK's set_position_ned mask

    def setpoint() -> None:
        gcs.mav.set_position_target_local_ned_send(
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, pos_yaw, here[0] + 1.0, here[1], -2.5,
            0, 0, 0, 0, 0, 0, 0.0, 0,
        )  # fmt: skip

    for _ in range(5):  # PX4 wants a stream before it switches
        setpoint()
        time.sleep(0.1)
    assert gcs.set_px4_mode("OFFBOARD") == ACCEPTED
    setpoint()
    gcs.wait_mode("OFFBOARD", 0.5)  # the heartbeat sent right after the change, well within COM_OF_LOSS_T
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        setpoint()
        last_sent = time.monotonic()
        time.sleep(0.1)
    assert abs(v.truth.pos_ned_m[0] - (here[0] + 1.0)) < 0.3
    gcs.wait_mode("LOITER", 3.0)  # COM_OF_LOSS_T = 1 s, then Hold
    assert 0.9 < time.monotonic() - last_sent < 2.5
    assert "Hold" in gcs.expect_text("offboard setpoints lost")
    time.sleep(1.0)
    assert v.armed and not v.crashed and abs(-v.truth.pos_ned_m[2] - 2.5) < 0.3


@pytest.mark.timeout(60)
async def test_offboard_loss_falls_back_to_hold_as_px4(udp_port: Callable[[], int]) -> None:
    await _run(udp_port(), "anchors8", _offboard_loss)


# -- missions over the wire ------------------------------------------------------------------------
def _upload(gcs: Gcs, items: list[tuple[int, int, int, float]], mission_type: int = 0) -> int:
    """Answer the vehicle's MISSION_REQUEST_INTs with (frame, command, x, y) items; the MISSION_ACK type."""
    gcs.mav.mission_count_send(1, 1, len(items), mission_type)
    while True:
        m = gcs.recv(["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], 2.0)
        if m.get_type() == "MISSION_ACK":
            return int(m.type)
        frame, command, x, y = items[m.seq]
        gcs.mav.mission_item_int_send(
            1, 1, m.seq, frame, command, int(m.seq == 0), 1, 0, 0.3, 0, math.nan, x, int(y), 2.5, mission_type
        )


def _download(gcs: Gcs, mission_type: int = 0) -> list[object]:
    gcs.mav.mission_request_list_send(1, 1, mission_type)
    count = gcs.recv("MISSION_COUNT", 2.0).count
    items = []
    for seq in range(count):
        gcs.mav.mission_request_int_send(1, 1, seq, mission_type)
        items.append(gcs.recv("MISSION_ITEM_INT", 2.0, lambda m, s=seq: m.seq == s))
    gcs.mav.mission_ack_send(1, 1, mav.MAV_MISSION_ACCEPTED, mission_type)
    return items


def _missions(runner: SimRunner, gcs: Gcs) -> None:
    v = _vehicle(runner)
    from secuav_common.geo import ned_to_geodetic

    gcs.recv("HEARTBEAT")
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    pts = [ned_to_geodetic(v.home, n, e, 0.0) for n, e in ((2.5, 1.0), (1.0, 1.0), (1.0, 2.5))]
    items = [(rel, mav.MAV_CMD_NAV_WAYPOINT, round(lat * 1e7), round(lon * 1e7)) for lat, lon, _ in pts]
    items.insert(1, (mav.MAV_FRAME_MISSION, mav.MAV_CMD_DO_CHANGE_SPEED, 0, 0))  # accepted, not flown
    assert _upload(gcs, items) == mav.MAV_MISSION_ACCEPTED
    back = _download(gcs)
    assert [(m.frame, m.command, m.x, m.y) for m in back] == items
    assert [it.speed_m_s for it in v.commander.nav.mission] == [None, pytest.approx(0.3), pytest.approx(0.3)]
    # fences and rally points are stored and returned (not enforced)
    fence = [(mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, items[0][2], items[0][3])]
    assert _upload(gcs, fence, mav.MAV_MISSION_TYPE_FENCE) == mav.MAV_MISSION_ACCEPTED
    assert [(m.command, m.x) for m in _download(gcs, mav.MAV_MISSION_TYPE_FENCE)] == [(fence[0][1], fence[0][2])]
    assert len(_download(gcs)) == 4  # the mission is untouched
    # an item the vehicle cannot fly is refused with a reason, and the old mission stays
    bad = [(rel, mav.MAV_CMD_NAV_LOITER_TURNS, items[0][2], items[0][3])]
    assert _upload(gcs, bad) == mav.MAV_MISSION_UNSUPPORTED
    assert "not supported" in gcs.expect_text("Mission item 0")
    assert len(v.commander.nav.mission) == 3
    # clear all
    gcs.mav.mission_clear_all_send(1, 1, mav.MAV_MISSION_TYPE_ALL)
    assert gcs.recv("MISSION_ACK", 2.0).type == mav.MAV_MISSION_ACCEPTED
    assert _download(gcs) == [] and v.commander.nav.mission == []


@pytest.mark.timeout(60)
async def test_mission_upload_download_fence_refusal_and_clear(udp_port: Callable[[], int]) -> None:
    await _run(udp_port(), "anchors8", _missions)


# -- a crash is reported and ends the flight -----------------------------------------------------------
def _crash(runner: SimRunner, gcs: Gcs) -> None:
    v = _vehicle(runner)
    gcs.recv("HEARTBEAT")
    # takeoff to a requested altitude: COMMAND_LONG param7 is AMSL, as PX4 reads it
    assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
    assert gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, v.home.alt_m + 3.0) == ACCEPTED
    gcs.wait_mode("LOITER", 12)
    time.sleep(0.5)
    assert abs(-v.truth.pos_ned_m[2] - 3.0) < 0.2
    forward = 1479  # velocity + yaw rate only: MAVSDK's set_velocity_body mask

    def push() -> None:
        gcs.mav.set_position_target_local_ned_send(
            0, 1, 1, mav.MAV_FRAME_BODY_NED, forward, 0, 0, 0, 3.0, 0, 0, 0, 0, 0, 0, 0
        )

    for _ in range(3):
        push()
        time.sleep(0.1)
    assert gcs.set_px4_mode("OFFBOARD") == ACCEPTED
    deadline = time.monotonic() + 6
    while not v.crashed:
        assert time.monotonic() < deadline, v.truth.pos_ned_m
        push()
        time.sleep(0.1)
    assert "collision with wall 'wall'" in gcs.expect_text("collision")
    hb = gcs.recv("HEARTBEAT", 2.0, lambda m: m.system_status == mav.MAV_STATE_EMERGENCY)
    assert not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == DENIED
    assert "crashed" in gcs.expect_text("Arming denied")
    assert v.truth.pos_ned_m[0] > 4.0  # it hit the wall 5 m north


@pytest.mark.timeout(60)
async def test_a_crash_into_the_wall_is_reported_and_ends_the_flight(udp_port: Callable[[], int]) -> None:
    await _run(udp_port(), "wall_hover", _crash)

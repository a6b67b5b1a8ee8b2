"""secuav-feed's parts without a network: the messages it builds, its truth decoding, its command line."""

from __future__ import annotations

import asyncio
import contextlib
import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as apm

from flightsim.api import ExternalPosition, ExternalRange, State
from flightsim.companion.cli import main
from flightsim.companion.feed import FeedBuilder
from flightsim.companion.truth import TlogTruth, TruthDecoder
from flightsim.control.rotation import quat_from_euler
from flightsim.mavlink import external
from flightsim.mavlink.wire import Decoder, Encoder
from mavframe.tlog import stamp
from secuav_common.geo import geodetic_to_ned, ned_to_geodetic
from secuav_common.scenario import load_scenario

SCENARIO = load_scenario("companion_feed")
HOME = SCENARIO.world.home


def truth(t: float, pos=(1.0, 0.5, -5.0), pitch=0.0) -> State:
    q = quat_from_euler(0.0, pitch, 0.3)
    return State(t, pos, (0.2, -0.1, 0.0), (0.0, 0.0, 0.0), q, (0.0, pitch, 0.3), (0.0, 0.0, 0.0))


def build(sensors: list[str], seconds: float = 1.0) -> tuple[Encoder, list]:
    enc = Encoder(1, 158)
    b = FeedBuilder(SCENARIO, 1, sensors, enc.mav)
    msgs = []
    for k in range(round(seconds * 50)):
        msgs.extend(b.messages(truth(k * 0.02)))
    return enc, msgs


def test_the_scenarios_rangefinders_go_out_at_their_rate_with_their_noise() -> None:
    _, msgs = build(["rangefinders"])
    down = [m for m in msgs if m.id == 0]
    wall = [m for m in msgs if m.id == 1]
    assert len(down) == len(wall) == 20  # 20 Hz each, over 1 s
    assert {m.orientation for m in down} == {25} and {m.orientation for m in wall} == {0}
    # 5 m up, 6 - 1 = 5 m short of the wall along a level beam yawed 0.3 rad: 5 / cos(0.3); noise std 2 cm
    assert all(abs(m.current_distance - 500) <= 10 for m in down)
    assert all(abs(m.current_distance - 500 / math.cos(0.3)) <= 10 for m in wall)
    assert len({m.current_distance for m in down}) > 3  # noisy, not a constant
    assert [m.time_boot_ms for m in down[:3]] == [0, 60, 100]  # due at 50 ms, made with the next state (60 ms)


def test_what_the_feed_sends_is_what_the_vehicle_decodes() -> None:
    enc, msgs = build(["rangefinders", "vision", "odometry"], seconds=0.2)
    dec = Decoder()
    readings = [external.decode(m) for m in dec.decode(b"".join(enc.pack(m) for m in msgs))]
    ranges = [r for r in readings if isinstance(r, ExternalRange)]
    fixes = [r for r in readings if isinstance(r, ExternalPosition)]
    assert ranges and all((r.src_sysid, r.src_compid) == (1, 158) for r in ranges)
    sent = [m.current_distance for m in msgs if m.get_type() == "DISTANCE_SENSOR"]
    assert [r.distance_m * 100 for r in ranges] == pytest.approx(sent)
    assert {f.message for f in fixes} == {"vision_position_estimate", "odometry"}
    assert all(math.dist(f.pos_ned_m, (1.0, 0.5, -5.0)) < 0.2 for f in fixes)  # std 2 cm per axis


def test_no_target_is_max_plus_one_centimetre_and_decodes_as_nan() -> None:
    enc = Encoder(1, 158)
    b = FeedBuilder(SCENARIO, 1, ["rangefinders"], enc.mav)
    msgs = b.messages(truth(0.0, pos=(1.0, 0.0, -45.0)))  # 45 m up: beyond the laser's 40 m
    down = next(m for m in msgs if m.id == 0)
    assert down.current_distance == down.max_distance + 1 == 4001
    r = external.decode(Decoder().decode(enc.pack(down))[0])
    assert isinstance(r, ExternalRange) and math.isnan(r.distance_m)


def test_gps_feeds_carry_the_true_position_in_their_units() -> None:
    _, msgs = build(["gps_input", "hil_gps"], seconds=0.5)
    gi = [m for m in msgs if m.get_type() == "GPS_INPUT"]
    hg = [m for m in msgs if m.get_type() == "HIL_GPS"]
    assert len(gi) == len(hg) == 5  # the scenario's GPS rate, 10 Hz
    alt = ned_to_geodetic(HOME, 1.0, 0.5, -5.0)[2]
    for m in gi:
        n, e, d = geodetic_to_ned(HOME, m.lat / 1e7, m.lon / 1e7, m.alt)
        assert math.dist((n, e, d), (1.0, 0.5, -5.0)) < 0.5  # GPS error: 5 cm horizontal, 8 cm vertical std
        assert m.fix_type == 3 and m.ignore_flags == 0 and 0 <= m.time_week_ms < 7 * 86400 * 1000
    for m in hg:
        assert abs(m.alt - alt * 1000) < 500 and abs(m.vn - 20) <= 20 and m.satellites_visible == 12


def test_an_unknown_sensor_or_a_missing_block_is_refused() -> None:
    with pytest.raises(ValueError, match="lidar"):
        FeedBuilder(SCENARIO, 1, ["lidar"], Encoder(1, 158).mav)
    with pytest.raises(ValueError, match=r"external\.uwb"):
        FeedBuilder(SCENARIO, 1, ["uwb"], Encoder(1, 158).mav)


def test_sitl_truth_messages_become_local_states() -> None:
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    lat, lon, alt = ned_to_geodetic(HOME, 3.0, -2.0, -7.0)
    q = quat_from_euler(0.1, 0.0, 0.0)
    sim_state = mav.sim_state_encode(*q, 0.1, 0, 0, 0, 0, 0, 0, 0, 0, lat, lon, alt, 0, 0, 1.0, 2.0, 0.5,
                                     round(lat * 1e7), round(lon * 1e7))  # fmt: skip
    hil = mav.hil_state_quaternion_encode(0, q, 0, 0, 0, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                                          100, 200, 50, 0, 0, 0, 0, 0)  # fmt: skip
    other = apm.MAVLink(None, srcSystem=2, srcComponent=1).sim_state_encode(*q, *[0] * 19)
    dec = TruthDecoder(HOME, 1)
    for msg in (sim_state, hil):
        msg.pack(mav)
        s = dec.decode(apm.MAVLink(None).decode(bytearray(msg.get_msgbuf())), 4.0)
        assert s is not None and s.t_s == 4.0
        assert s.pos_ned_m == pytest.approx((3.0, -2.0, -7.0), abs=0.01)
        assert s.vel_ned_m_s == pytest.approx((1.0, 2.0, 0.5))
        assert s.euler_rad[0] == pytest.approx(0.1, abs=1e-6)
    other.pack(apm.MAVLink(None, srcSystem=2))
    assert dec.decode(apm.MAVLink(None).decode(bytearray(other.get_msgbuf())), 0.0) is None  # another system


def test_a_recording_replays_its_truth_in_order(tmp_path: Path) -> None:
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    log = tmp_path / "sitl.tlog"
    blob = b""
    for k in range(5):
        lat, lon, alt = ned_to_geodetic(HOME, float(k), 0.0, -5.0)
        msg = mav.sim_state_encode(1, 0, 0, 0, *[0] * 9, lat, lon, alt, 0, 0, 0, 0, 0,
                                   round(lat * 1e7), round(lon * 1e7))  # fmt: skip
        blob += stamp(1000.0 + 0.1 * k) + msg.pack(mav)
    log.write_bytes(blob)

    async def collect() -> list[State]:
        return [s async for s in TlogTruth(log, HOME, 1, speed=0).states()]

    states = asyncio.run(collect())
    assert [round(s.t_s, 3) for s in states] == [0.0, 0.1, 0.2, 0.3, 0.4]
    assert [s.pos_ned_m[0] for s in states] == pytest.approx([0.0, 1.0, 2.0, 3.0, 4.0], abs=0.02)  # 1e-7 deg: 1 cm


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["companion_feed", "--to", "tcp://127.0.0.1:5760"], "--to tcp://127.0.0.1:5760"),
        (["companion_feed", "--to", "udpout://127.0.0.1:9", "--sensors", "lidar"], "'lidar'"),
        (["companion_feed", "--to", "udpout://127.0.0.1:9", "--sysid", "7"], "--sysid 7"),
        (["companion_feed", "--to", "udpout://127.0.0.1:9", "--rate", "0"], "--rate 0"),
        (["wall_hover", "--to", "udpout://127.0.0.1:9"], "no external block"),
        (["companion_feed", "--to", "udpout://127.0.0.1:9", "--sensors", "uwb"], "external.uwb"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err and err.startswith("secuav-feed: ")


def sim_state_tlog(path: Path, heights: list[float], period_s: float = 0.05, restart_at: int | None = None) -> None:
    """A recording of SITL truth: SIM_STATE of system 1 climbing through ``heights``; its clock starts again
    at entry ``restart_at`` (a simulator restarted while recording)."""
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    blob = b""
    for i, h in enumerate(heights):
        k = i if restart_at is None or i < restart_at else i - restart_at
        lat, lon, alt = ned_to_geodetic(HOME, 0.0, 0.0, -h)
        msg = mav.sim_state_encode(1, 0, 0, 0, *[0] * 9, lat, lon, alt, 0, 0, 0, 0, 0,
                                   round(lat * 1e7), round(lon * 1e7))  # fmt: skip
        blob += stamp(1000.0 + period_s * k) + msg.pack(mav)
    path.write_bytes(blob)


def test_the_command_feeds_a_recording_to_a_udp_peer_and_ends_with_it(
    tmp_path: Path, udp_port, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    log = tmp_path / "sitl.tlog"
    sim_state_tlog(log, [3.0 + 0.01 * k for k in range(40)])  # 2 s at 20 Hz
    port = udp_port()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.5)
        argv = ["companion_feed", "--to", f"udpout://127.0.0.1:{port}", "--truth", str(log), "--speed", "0",
                "--sensors", "rangefinders", "--compid", "197"]  # fmt: skip
        assert main(argv) == 0
        frames = []
        with contextlib.suppress(TimeoutError):
            while True:
                frames.append(sock.recv(2048))
    msgs = Decoder().decode(b"".join(frames))
    down = [m for m in msgs if m.get_type() == "DISTANCE_SENSOR" and m.id == 0]
    assert len(down) == 40  # one per truth sample: the recording's 20 Hz is the laser's rate
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in msgs} == {(1, 197)}
    assert all(abs(m.current_distance - (300 + k)) <= 10 for k, m in enumerate(down))  # noise std 2 cm
    out = capsys.readouterr().out
    assert "stopped after 40 states, DISTANCE_SENSOR=80" in out


def test_a_restarted_simulator_is_fed_again_from_its_new_clock(tmp_path: Path, udp_port) -> None:
    import socket

    log = tmp_path / "restart.tlog"
    sim_state_tlog(log, [3.0] * 40 + [4.0] * 40, restart_at=40)
    port = udp_port()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.5)
        argv = ["companion_feed", "--to", f"udpout://127.0.0.1:{port}", "--truth", str(log), "--speed", "0",
                "--sensors", "rangefinders", "-q"]  # fmt: skip
        assert main(argv) == 0
        frames = []
        with contextlib.suppress(TimeoutError):
            while True:
                frames.append(sock.recv(2048))
    down = [m for m in Decoder().decode(b"".join(frames)) if m.get_type() == "DISTANCE_SENSOR" and m.id == 0]
    assert len(down) == 80 and abs(down[-1].current_distance - 400) <= 10  # the second run fed, not skipped


async def test_a_sitl_truth_source_asks_for_its_truth_and_reads_it(udp_port) -> None:
    """The source over real UDP against a pymavlink peer: SET_MESSAGE_INTERVAL goes out, SIM_STATE comes back."""
    from flightsim.companion.truth import MavlinkTruth
    from secuav_common.urls import Endpoint

    port = udp_port()
    loop = asyncio.get_running_loop()
    asked: list[int] = []
    parser = apm.MAVLink(None)
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    lat, lon, alt = ned_to_geodetic(HOME, 1.0, 2.0, -3.0)
    sim_state = mav.sim_state_encode(1, 0, 0, 0, *[0] * 9, lat, lon, alt, 0, 0, 0, 0, 0,
                                     round(lat * 1e7), round(lon * 1e7))  # fmt: skip

    class Sitl(asyncio.DatagramProtocol):
        def connection_made(self, transport) -> None:
            self.t = transport

        def datagram_received(self, data: bytes, addr) -> None:
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "COMMAND_LONG" and m.command == apm.MAV_CMD_SET_MESSAGE_INTERVAL:
                    asked.append(int(m.param1))
                    self.t.sendto(sim_state.pack(mav), addr)

    transport, _ = await loop.create_datagram_endpoint(Sitl, local_addr=("127.0.0.1", port))
    try:
        source = MavlinkTruth(Endpoint("udpout", "127.0.0.1", port), HOME, 1)
        states = source.states()
        first = await asyncio.wait_for(anext(states), 5.0)
        await states.aclose()
    finally:
        transport.close()
    assert set(asked) == {apm.MAVLINK_MSG_ID_SIM_STATE, apm.MAVLINK_MSG_ID_HIL_STATE_QUATERNION}
    assert first.pos_ned_m == pytest.approx((1.0, 2.0, -3.0), abs=0.02)

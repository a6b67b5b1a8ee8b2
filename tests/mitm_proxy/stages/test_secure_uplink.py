"""The secure stage toward the vehicle (issue 33, item 5): three MAVLink rangefinders a companion feeds to the
autopilot, one biased by a rule toward the vehicle; the stage sits on the uplink and the autopilot receives
the secure distance, while everything the vehicle sends leaves byte for byte.

Sans I/O: one link's real pipeline (tap -> attack -> secure -> forward) with the real engine and estimator,
fed pymavlink frames on a simulated clock (the inline executor: every frame sees the estimate of the set
before it, deterministically).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.stages.secure.config import SecureConfig, config_from_payload
from mitm_proxy.stages.secure.stage import FLAGGED_QUALITY
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario, load_scenario
from tests.support.uplink_bench import Run, UplinkBench

TRUE_M, NOISE_M, BIAS_M = 5.0, 0.012, 3.0  # the scenario's hover height and its rangefinders' noise
DS = 132
TOWARD_VEHICLE = {"message": "DISTANCE_SENSOR", "sensor_id": 1, "direction": "uplink"}
FEED = {"name": "feed-lie", "rules": [{"target": TOWARD_VEHICLE, "kind": "bias", "offset": BIAS_M}]}


@pytest.fixture(scope="module")
def height() -> Scenario:
    return load_scenario("ardupilot_height")  # three downward rangefinders, ids 0-2


def fly(height: Scenario, secure: SecureConfig | None, seconds: float = 12.0, fed: tuple[int, ...] = (0, 1, 2)) -> Run:
    """A companion (sysid 1, compid 197) sends the ``fed`` ids at 10 Hz toward the vehicle, each its own datagram;
    the vehicle sends ATTITUDE, LOCAL_POSITION_NED, its own echo of the fed ones (ArduPilot re-reports a
    MAVLink rangefinder) and its own reading of the others toward the ground."""
    bench = UplinkBench(height, FEED, "feed.yaml", secure)
    companion, vehicle, send, run = bench.companion, bench.vehicle, bench.send, bench.run
    rng = random.Random(7)

    start_s = time.monotonic()  # the profile's activation clock started at install
    for k in range(int(seconds * 10)):
        t_s, ms = start_s + k * 0.1, 1000 + k * 100
        for sid in fed:
            cm = round((TRUE_M + rng.gauss(0.0, NOISE_M)) * 100)
            send(companion, mavlink.MAVLink_distance_sensor_message(ms, 20, 4000, cm, 0, sid, 25, 0),
                 Direction.UPLINK, t_s + 0.001 * sid)  # fmt: skip
        send(vehicle, mavlink.MAVLink_attitude_message(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), Direction.DOWNLINK, t_s)
        send(vehicle, mavlink.MAVLink_local_position_ned_message(ms, 0.0, 0.0, -TRUE_M, 0.0, 0.0, 0.0),
             Direction.DOWNLINK, t_s + 0.002)  # fmt: skip
        for sid in range(3):  # the echo of what the autopilot got (a fixed 5.00 m), or its own sensor's reading
            cm = 500 if sid in fed else round((TRUE_M + rng.gauss(0.0, NOISE_M)) * 100)
            send(vehicle, mavlink.MAVLink_distance_sensor_message(ms, 20, 4000, cm, 0, sid, 25, 0),
                 Direction.DOWNLINK, t_s + 0.003)  # fmt: skip
    return run


def received(frames: list[bytes], after: int = 30) -> dict[int, list[tuple[float, int]]]:
    """Sensor id -> (distance m, signal_quality) of each DISTANCE_SENSOR the autopilot got, after the warm-up."""
    mav = mavlink.MAVLink(None)
    out: dict[int, list[tuple[float, int]]] = {}
    for raw in frames[after * 3:]:
        msg = mav.parse_char(bytearray(raw))
        out.setdefault(msg.id, []).append((msg.current_distance / 100.0, msg.signal_quality))
    return out


def test_without_the_stage_the_autopilot_gets_the_lie(height: Scenario) -> None:
    run = fly(height, None)
    got = received(run.up_out)
    assert all(abs(d - (TRUE_M + BIAS_M)) < 0.05 for d, _ in got[1])  # the rule toward the vehicle acts
    assert all(abs(d - TRUE_M) < 0.05 for d, _ in got[0] + got[2])
    assert run.down_out == run.down_in


def test_on_the_uplink_the_autopilot_gets_the_secure_distance_and_the_downlink_is_untouched(
    height: Scenario,
) -> None:
    cfg = SecureConfig(estimator="secekf", executor="inline", direction="uplink")
    run = fly(height, cfg)
    got = received(run.up_out)
    assert set(got) == {0, 1, 2} and len(run.up_out) == len(run.up_in)
    for sid in (0, 1, 2):  # every reading the autopilot fuses is the secure one, within the noise
        errors = [abs(d - TRUE_M) for d, _ in got[sid]]
        assert max(errors) < 4 * NOISE_M + 0.01, (sid, max(errors))
    assert all(q == FLAGGED_QUALITY for _, q in got[1][5:])  # the biased sensor is flagged as such
    assert run.down_out == run.down_in  # what the vehicle sends leaves byte for byte, its echo among it


def test_on_the_downlink_as_before_the_fed_lie_passes_to_the_autopilot(height: Scenario) -> None:
    cfg = SecureConfig(estimator="secekf", executor="inline")  # the default: the stage shields the ground
    run = fly(height, cfg)
    got = received(run.up_out)
    assert all(abs(d - (TRUE_M + BIAS_M)) < 0.05 for d, _ in got[1])
    # the stage never touched the uplink: the two honest sensors reach the autopilot byte for byte
    honest_in = [raw for k, raw in enumerate(run.up_in) if k % 3 != 1]
    honest_out = [raw for k, raw in enumerate(run.up_out) if k % 3 != 1]
    assert honest_out == honest_in


def test_on_both_a_group_split_between_directions_is_read_and_rewritten_both_ways(height: Scenario) -> None:
    """Two rangefinders a companion feeds (id 1 biased on its way), one the vehicle has itself (id 2): one group,
    and the secure distance goes both to the autopilot and to the ground."""
    run = fly(height, SecureConfig(estimator="secekf", executor="inline", direction="both"), fed=(0, 1))
    mav = mavlink.MAVLink(None)
    up = [mav.parse_char(bytearray(raw)) for raw in run.up_out[40:]]
    down = [m for raw in run.down_out[100:] if (m := mav.parse_char(bytearray(raw))).get_type() == "DISTANCE_SENSOR"]
    assert {m.id for m in up} == {0, 1} and {m.id for m in down} == {0, 1, 2}
    for m in up + down:  # the autopilot and the ground get the secure distance, within the noise
        assert abs(m.current_distance / 100.0 - TRUE_M) < 4 * NOISE_M + 0.01, (m.id, m.current_distance)
    assert all(m.signal_quality == FLAGGED_QUALITY for m in up if m.id == 1)
    assert run.up_out != run.up_in and run.down_out != run.down_in  # both ways rewritten


def test_the_direction_is_checked_like_every_other_field() -> None:
    assert config_from_payload({"estimator": "secekf", "direction": "uplink"}).direction == "uplink"
    assert config_from_payload("secekf").direction == "downlink"
    with pytest.raises(InputError) as err:
        config_from_payload({"estimator": "secekf", "direction": "sideways"}, "secure/set")
    assert "direction" in str(err.value) and "sideways" in str(err.value)


@pytest.mark.timeout(90)
@pytest.mark.usefixtures("proxy_path")  # on the fast path and the Python one (tests/conftest.py)
def test_the_real_proxy_substitutes_toward_the_vehicle(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    """``secuav-proxy --secure secekf --secure-direction uplink`` as a process: a companion on a ground endpoint
    feeds three rangefinders over UDP, one biased by ``--profile``; the vehicle's socket receives the secure
    distance, and what the vehicle sends reaches the companion byte for byte."""
    veh_port, gnd_port = udp_port(), udp_port()
    profile = tmp_path / "feed.yaml"
    profile.write_text(json.dumps(FEED), encoding="utf-8")
    log = tmp_path / "proxy.log"
    with log.open("wb") as sink:
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", "none", "--scenario", "ardupilot_height",
             "--secure", "secekf", "--secure-direction", "uplink", "--profile", str(profile),
             "--vehicle", f"udpin://127.0.0.1:{veh_port}", "--ground", f"udpin://127.0.0.1:{gnd_port}"],
            stdout=sink, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    companion = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.settimeout(0.05)
    companion.settimeout(0.05)
    veh_mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    comp_mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=197)
    rng = random.Random(3)
    got: list[tuple[int, float, int]] = []  # (id, m, quality) of what the vehicle received
    sent_down: list[bytes] = []
    heard_down: list[bytes] = []
    try:
        deadline = time.monotonic() + 40.0
        ms = 1000
        while time.monotonic() < deadline and len(got) < 240:
            assert proxy.poll() is None, log.read_text()
            beat = bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(veh_mav))
            sent_down.append(beat)
            vehicle.sendto(beat, ("127.0.0.1", veh_port))  # the proxy learns where the vehicle is
            for sid in range(3):
                cm = round((TRUE_M + rng.gauss(0.0, NOISE_M)) * 100)
                msg = mavlink.MAVLink_distance_sensor_message(ms, 20, 4000, cm, 0, sid, 25, 0)
                companion.sendto(bytes(msg.pack(comp_mav)), ("127.0.0.1", gnd_port))
            ms += 100
            end = time.monotonic() + 0.1
            while time.monotonic() < end:
                for sock, sink_list in ((vehicle, None), (companion, heard_down)):
                    with contextlib.suppress(TimeoutError):
                        data = sock.recv(65536)
                        if sink_list is not None:
                            sink_list += [r for _h, r in split(data).frames]
                            continue
                        for h, raw in split(data).frames:
                            if h.msgid == DS:
                                m = mavlink.MAVLink(None).parse_char(bytearray(raw))
                                got.append((m.id, m.current_distance / 100.0, m.signal_quality))
    finally:
        proxy.send_signal(signal.SIGTERM)
        try:
            proxy.wait(10)
        finally:
            if proxy.poll() is None:
                proxy.kill()
        vehicle.close()
        companion.close()
    assert len(got) >= 240, log.read_text()
    late = got[-90:]  # the last 3 s: the estimator has long converged
    assert {sid for sid, _, _ in late} == {0, 1, 2}
    assert max(abs(d - TRUE_M) for _, d, _ in late) < 4 * NOISE_M + 0.01, late
    assert all(q == FLAGGED_QUALITY for sid, _, q in late if sid == 1)
    assert heard_down and set(heard_down) <= set(sent_down)  # the downlink: byte for byte
    text = log.read_text()
    said = [ln for ln in text.splitlines() if " attack.vehicle_reports " in ln]  # once, after proxy.ready
    assert len(said) == 1 and "reports the lie itself" in said[0], text
    assert "secure=secekf secure_on=\"toward the vehicle\"" in text and "changes=\"toward the vehicle\"" in text, text

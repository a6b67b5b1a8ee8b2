"""Quantity targets on real streams: a recorded ArduCopter flight and a flightsim (PX4-like) run go
through the attack stage, and afterwards no message still carries the true value of an attacked
quantity, while every frame that carries none of them leaves byte for byte (issue 27, item 1).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from attack_profiles.profile import parse_profile
from flightsim.runner import RunConfig, SimRunner
from mavframe import tlog
from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint
from tests.attack_profiles.quantity_check import Checker, Offsets, Report

ARDUPILOT_TLOG = Path(__file__).resolve().parents[1] / "data" / "ardupilot-copter-guided.tlog"
OFFSETS = Offsets(range_m=5.0, range_ids=frozenset({0}), up_m=3.0, north_m=7.0, east_m=-4.0)


def through_stage(frames: list[tuple[bytes, Direction]], offsets: Offsets) -> list[bytes]:
    """Each frame as its own datagram through one link's pipeline with the attack stage; the frames that leave."""
    slot = AttackSwitch(AttackSlot(1))
    state = slot.offer(parse_profile(offsets.profile(), "quantities.yaml"))
    assert state.ok, state.error
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    out: list[bytes] = []
    now = time.monotonic()
    for raw, direction in frames:
        for item in pipe.feed(raw, direction, now):
            out += [r for _h, r in split(item.data).frames]
    return out


def recorded_through_stage(path: Path) -> Report:
    """A recorded .tlog (the ground station's frames uplink, the rest downlink) through the stage, checked."""
    frames = [(e.raw, Direction.UPLINK if e.header.sysid == 255 else Direction.DOWNLINK) for e in tlog.read(path)]
    return Checker(OFFSETS).check([raw for raw, _ in frames], through_stage(frames, OFFSETS))


def test_recorded_ardupilot_flight_keeps_no_true_copy() -> None:
    report = recorded_through_stage(ARDUPILOT_TLOG)
    s = report.shifted
    # Every carrier ArduPilot sends was rewritten, both rangefinder messages among them.
    for name in ("DISTANCE_SENSOR.current_distance", "RANGEFINDER.distance", "GLOBAL_POSITION_INT.alt",
                 "GLOBAL_POSITION_INT.relative_alt", "GLOBAL_POSITION_INT.lat", "GLOBAL_POSITION_INT.lon",
                 "LOCAL_POSITION_NED.x", "LOCAL_POSITION_NED.y", "LOCAL_POSITION_NED.z", "VFR_HUD.alt",
                 "GPS_RAW_INT.lat", "GPS_RAW_INT.alt", "TERRAIN_REPORT.current_height", "TERRAIN_REPORT.lat",
                 "AHRS2.altitude", "AHRS2.lng", "SIMSTATE.lat", "SIMSTATE.lng"):  # fmt: skip
        assert s[name] > 0, name
    # On the ground the rangefinders read 0-1 cm, below min_distance 20 cm: those stay no reading.
    assert report.kept["DISTANCE_SENSOR.current_distance"] > 0 and report.kept["RANGEFINDER.distance"] > 0
    assert report.exact > 10_000  # parameters, mission, IMU, status...: untouched
    print(f"shifted {dict(s)} kept {dict(report.kept)} exact {report.exact}")


def _flightsim_frames(duration_s: float = 6.0) -> list[bytes]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    port = sock.getsockname()[1]
    got: list[bytes] = []

    async def run() -> None:
        loop = asyncio.get_running_loop()
        cfg = RunConfig(load_scenario("wall_hover"), [Endpoint("udpout", "127.0.0.1", port)], speed=4.0,
                        duration_s=duration_s)  # fmt: skip
        stop = asyncio.Event()
        async with SimRunner(cfg) as runner:
            task = asyncio.create_task(runner.run(stop))
            while not task.done():
                with contextlib.suppress(TimeoutError):
                    got.append(await asyncio.wait_for(loop.sock_recv(sock, 65536), 0.2))
            await task

    try:
        asyncio.run(run())
    finally:
        sock.close()
    return [raw for datagram in got for _h, raw in split(datagram).frames]


@pytest.mark.timeout(60)
def test_flightsim_stream_keeps_no_true_copy() -> None:
    frames = _flightsim_frames()
    offsets = Offsets(range_m=2.0, up_m=3.0, north_m=7.0, east_m=-4.0)  # every rangefinder of the wall demo
    out = through_stage([(raw, Direction.DOWNLINK) for raw in frames], offsets)
    report = Checker(offsets).check(frames, out)
    s = report.shifted
    for name in ("DISTANCE_SENSOR.current_distance", "GLOBAL_POSITION_INT.alt", "GLOBAL_POSITION_INT.lat",
                 "LOCAL_POSITION_NED.z", "LOCAL_POSITION_NED.x", "VFR_HUD.alt", "ALTITUDE.altitude_amsl",
                 "ALTITUDE.bottom_clearance", "GPS_RAW_INT.lat", "GPS_RAW_INT.alt"):  # fmt: skip
        assert s[name] > 0, name
    print(f"shifted {dict(s)} kept {dict(report.kept)} exact {report.exact}")


@pytest.mark.timeout(90)
def test_real_proxy_on_loopback_rewrites_every_carrier_and_keeps_no_reading(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    """``secuav-proxy --profile F`` as a process, the recorded ArduCopter stream sent to it over UDP."""
    veh, gcs = udp_port(), udp_port()
    profile = tmp_path / "quantities.yaml"
    profile.write_text(yaml.safe_dump(OFFSETS.profile()), encoding="utf-8")
    frames = [e.raw for e in tlog.read(ARDUPILOT_TLOG) if e.header.sysid == 1]
    ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 23)
    ground.bind(("127.0.0.1", gcs))
    ground.settimeout(0.2)
    log = tmp_path / "proxy.log"
    with log.open("wb") as sink:
        proxy = subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--broker", "none", "--profile", str(profile),
             "--vehicle", f"udpin://127.0.0.1:{veh}", "--ground", f"udpout://127.0.0.1:{gcs}"],
            stdout=sink, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        # The first frame (a HEARTBEAT) until the proxy forwards it: then it is up.
        deadline = time.monotonic() + 30.0
        got: list[bytes] = []
        while not got:
            assert time.monotonic() < deadline and proxy.poll() is None, log.read_text()
            vehicle.sendto(frames[0], ("127.0.0.1", veh))
            with contextlib.suppress(TimeoutError):
                got.append(ground.recv(65536))
        received: list[bytes] = []
        done = threading.Event()

        def drain() -> None:
            while not done.is_set() or len(received) < len(frames) - 1:
                try:
                    received.append(ground.recv(65536))
                except TimeoutError:
                    if done.is_set():
                        return

        reader = threading.Thread(target=drain)
        reader.start()
        for k, raw in enumerate(frames[1:]):
            vehicle.sendto(raw, ("127.0.0.1", veh))
            if k % 20 == 19:
                time.sleep(0.002)  # a radio's pace, well above the 100 Hz the recording was made at
        time.sleep(1.0)
        done.set()
        reader.join(10)
    finally:
        proxy.send_signal(signal.SIGTERM)
        try:
            proxy.wait(10)
        finally:
            if proxy.poll() is None:
                proxy.kill()
        vehicle.close()
        ground.close()
    # The warm-up heartbeats were forwarded too: keep only what the stream itself became.
    out = [raw for datagram in received for _h, raw in split(datagram).frames]
    sent = frames[1:]
    out = out[len(out) - len(sent) :] if len(out) >= len(sent) else out
    report = Checker(OFFSETS).check(sent, out)
    assert report.shifted["RANGEFINDER.distance"] > 0 and report.shifted["DISTANCE_SENSOR.current_distance"] > 0
    assert report.kept["DISTANCE_SENSOR.current_distance"] > 0  # on the ground: 0 cm stayed 0 cm
    assert report.shifted["GLOBAL_POSITION_INT.lat"] > 0 and report.shifted["LOCAL_POSITION_NED.z"] > 0
    # What the table does not cover, said when applied: a structured line, not the bare event name.
    said = [line for line in log.read_text().splitlines() if "attack.true_copy" in line and "proxy.stats" not in line]
    assert said and all(" WARNING attack.true_copy sysid=" in line and " warning=" in line for line in said), said

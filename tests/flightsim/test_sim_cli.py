"""``secuav-sim`` as a user runs it: bad input, clean stop on signals, headless runs, ground truth out."""

from __future__ import annotations

import asyncio
import csv
import json
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import aiomqtt
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from flightsim.runner import RunConfig, SimRunner
from secuav_common.broker import EmbeddedBroker
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint

SIM = [sys.executable, "-m", "flightsim"]
BAD_SCENARIO = """\
name: bad
vehicles:
  - sysid: 1
    start: {pos_ned_m: [0, 0, 0]}
    sensors:
      rangefinders:
        - {id: 0, type: lidar}
"""


def _sim(*args: str, timeout_s: float = 20) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*SIM, *args], capture_output=True, text=True, timeout=timeout_s)


@pytest.mark.timeout(60)
def test_bad_input_is_one_line_naming_file_field_and_value_and_nothing_starts(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(BAD_SCENARIO)
    cases = {
        (str(bad),): [str(bad), "vehicles[0].sensors.rangefinders[0].type", "'lidar'"],
        (str(tmp_path / "missing.yaml"),): ["missing.yaml"],
        ("anchors8", "--mavlink", "quic://127.0.0.1:1"): ["quic://127.0.0.1:1", "scheme"],
        ("anchors8", "--mavlink", "tcp://127.0.0.1:1"): ["tcp://127.0.0.1:1", "tcpin://"],
        ("anchors8", "--mavlink", "tcpin://127.0.0.1:5760", "--gcs", "udpout://127.0.0.1:14550"): ["connects to"],
        ("formation", "--mavlink", "udpout://127.0.0.1:1", "--mavlink", "udpout://127.0.0.1:2", "--mavlink",
         "udpout://127.0.0.1:3"): ["--mavlink given 3 times"],
        ("anchors8", "--speed", "-2"): ["--speed -2"],
        ("anchors8", "--duration", "0"): ["--duration 0"],
        ("anchors8", "--broker", "http://127.0.0.1"): ["http://127.0.0.1"],
        ("anchors8", "--gcs", "udpin://127.0.0.1:14550"): ["--gcs udpin://127.0.0.1:14550", "udpout"],
    }  # fmt: skip
    for args, needles in cases.items():
        r = _sim(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("secuav-sim: error: "), (args, r.stderr)
        for needle in needles:
            assert needle in lines[0], (args, lines[0])
        assert "sim.start" not in r.stderr and r.stdout == ""


@pytest.mark.timeout(60)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_simulator_cleanly_within_a_second(sig: signal.Signals, udp_port: Callable[[], int]) -> None:
    port = udp_port()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:
        listener.bind(("127.0.0.1", port))
        listener.settimeout(20)
        proc = subprocess.Popen(
            [*SIM, "formation", "--mavlink", f"udpout://127.0.0.1:{port}", "--mavlink", f"udpout://127.0.0.1:{port}"],
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            listener.recv(2048)  # it is up and sending
            time.sleep(0.3)
            signalled_at = _latest_boot_ms(listener) / 1000.0  # the simulated time it had sent when signalled
            proc.send_signal(sig)
            rc = proc.wait(timeout=20)  # a hang fails here; how long the exit takes on a loaded machine does not
        finally:
            if proc.poll() is None:
                proc.kill()
        err = proc.stderr.read() if proc.stderr else ""
    assert rc == 0, err
    assert "sim.stop" in err and "Traceback" not in err
    # Within a second of simulated time (the sim's own clock, which a starved process does not advance): a
    # stop that waited out a timeout or a few more steps would run the clock on.
    stopped_at = float(re.search(r"sim\.stop sim_t_s=([0-9.]+)", err).group(1))  # type: ignore[union-attr]
    assert stopped_at - signalled_at < 1.0, (signalled_at, stopped_at)


def _latest_boot_ms(sock: socket.socket) -> int:
    """The highest ``time_boot_ms`` (simulated time) among the frames waiting on ``sock``."""
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    latest = 0
    sock.setblocking(False)
    try:
        while True:
            for msg in parser.parse_buffer(sock.recv(65535)) or []:
                latest = max(latest, getattr(msg, "time_boot_ms", 0))
    except BlockingIOError:
        pass
    finally:
        sock.setblocking(True)
    assert latest > 0
    return latest


@pytest.mark.timeout(60)
def test_fast_mode_runs_headless_and_writes_truth_csv(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    out = tmp_path / "truth.csv"
    port = udp_port()
    args = (
        "formation",
        "--fast",
        "--duration",
        "10",
        "--truth-csv",
        str(out),
        "--mavlink",
        f"udpout://127.0.0.1:{port}",
    )
    r = _sim(*args)
    assert r.returncode == 0, r.stderr
    stop = next(line for line in r.stderr.splitlines() if "sim.stop" in line)
    fields = dict(kv.split("=", 1) for kv in stop.split() if "=" in kv)
    assert float(fields["sim_t_s"]) == pytest.approx(10.0, abs=0.03)
    assert float(fields["rtf"]) > 2.0  # as fast as possible, not wall clock
    rows = list(csv.DictReader(out.open()))
    start = {v.sysid: v.start.pos_ned_m for v in load_scenario("formation").vehicles}
    for sysid in (1, 2):
        mine = [r for r in rows if int(r["sysid"]) == sysid]
        assert 190 <= len(mine) <= 201  # 20 Hz for 10 s
        times = [float(r["t_s"]) for r in mine]
        assert times == sorted(times)
        last = mine[-1]  # parked where the scenario put it
        assert abs(float(last["north_m"]) - start[sysid][0]) < 0.01
        assert abs(float(last["east_m"]) - start[sysid][1]) < 0.01
        assert last["collided"] == "0"
    # same seed, same truth
    again = tmp_path / "again.csv"
    r2 = _sim(*args[:4], "--truth-csv", str(again), *args[6:])
    assert r2.returncode == 0 and again.read_text() == out.read_text()


@pytest.mark.timeout(60)
async def test_truth_goes_to_mqtt_per_vehicle(tcp_port: Callable[[], int], udp_port: Callable[[], int]) -> None:
    port = tcp_port()
    async with EmbeddedBroker(port=port) as broker:
        assert broker.started
        async with aiomqtt.Client("127.0.0.1", port, identifier="truth-test") as client:
            await client.subscribe("secuav/+/truth")
            cfg = RunConfig(
                load_scenario("formation"),
                [Endpoint("udpout", "127.0.0.1", udp_port()), Endpoint("udpout", "127.0.0.1", udp_port())],
                broker=broker.address,
            )
            seen: dict[str, list[dict[str, object]]] = {}
            stop = asyncio.Event()
            async with SimRunner(cfg) as runner:
                task = asyncio.create_task(runner.run(stop))

                async def collect() -> None:
                    async for msg in client.messages:
                        seen.setdefault(str(msg.topic), []).append(json.loads(bytes(msg.payload)))  # type: ignore[arg-type]
                        if all(len(seen.get(f"secuav/v{s}/truth", [])) >= 10 for s in (1, 2)):
                            return

                await asyncio.wait_for(collect(), 15)
                stop.set()
                await task
    for sysid, start in ((1, (4.0, 4.0)), (2, (1.0, 1.0))):
        samples = seen[f"secuav/v{sysid}/truth"]
        assert all(s["sysid"] == sysid for s in samples)
        t = [float(s["t_s"]) for s in samples]  # type: ignore[arg-type]
        assert t == sorted(t)
        pos = samples[-1]["pos_ned_m"]
        assert abs(pos[0] - start[0]) < 0.01 and abs(pos[1] - start[1]) < 0.01  # type: ignore[index]
        assert samples[-1]["collided"] is False


@pytest.mark.timeout(30)
def test_gcs_option_streams_every_vehicle_to_one_more_port(udp_port: Callable[[], int]) -> None:
    api, gcs = udp_port(), udp_port()
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as api_sock,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs_sock,
    ):
        api_sock.bind(("127.0.0.1", api))
        gcs_sock.bind(("127.0.0.1", gcs))
        proc = subprocess.Popen(
            [*SIM, "formation", "--mavlink", f"udpout://127.0.0.1:{api}", "--gcs", f"udpout://127.0.0.1:{gcs}", "-q"],
            stderr=subprocess.PIPE,
        )
        try:
            on_gcs = _heartbeat_sysids(gcs_sock, want={1, 2})
            on_api = _heartbeat_sysids(api_sock, want={1})
        finally:
            proc.terminate()
            proc.wait(timeout=5)
    assert on_gcs == {1, 2}  # both vehicles on the one GCS port, told apart by sysid
    assert on_api == {1}  # vehicle 2 streams to api + 1


def _heartbeat_sysids(sock: socket.socket, want: set[int], timeout_s: float = 10.0) -> set[int]:
    from pymavlink.dialects.v20 import common as mavlink

    parser = mavlink.MAVLink(None)
    seen: set[int] = set()
    sock.settimeout(timeout_s)
    end = time.monotonic() + timeout_s
    while not want <= seen and time.monotonic() < end:
        for msg in parser.parse_buffer(sock.recv(65536)) or []:
            if msg.get_type() == "HEARTBEAT":
                seen.add(msg.get_srcSystem())
    return seen

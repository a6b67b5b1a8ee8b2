"""``secuav-proxy`` as a user runs it: a subprocess between ``secuav-sim`` and a pymavlink GCS.

The parameter protocol is a real round trip (PARAM_REQUEST_LIST -> every
PARAM_VALUE, PARAM_SET -> PARAM_VALUE with the new value); the recording is
read back with pymavlink's own tlog reader (what mavlogdump uses); SIGINT and
SIGTERM stop the daemon within a second with exit code 0.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]
BIN = Path(sys.executable).parent


def spawn(argv: list[str], log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as sink:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        return subprocess.Popen(argv, stdout=sink, stderr=subprocess.STDOUT, env=env)


def stop(proc: subprocess.Popen[bytes], sig: int) -> tuple[int, float]:
    t0 = time.monotonic()
    proc.send_signal(sig)
    try:
        code = proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    return code, time.monotonic() - t0


@pytest.fixture
def running(tmp_path: Path, udp_port: Callable[[], int]) -> Iterator[tuple[subprocess.Popen[bytes], int, Path]]:
    veh, gcs = udp_port(), udp_port()
    proxy = spawn([sys.executable, "-m", "mitm_proxy", "--broker", "none", "--vehicle", f"udpin://127.0.0.1:{veh}",
                   "--ground", f"udpout://127.0.0.1:{gcs}", "--record", str(tmp_path / "rec"),
                   "--stats-interval", "0.5"], tmp_path / "proxy.log")  # fmt: skip
    time.sleep(1.0)
    sim = spawn([str(BIN / "secuav-sim"), "wall_hover", "--mavlink", f"udpout://127.0.0.1:{veh}"], tmp_path / "sim.log")
    try:
        yield proxy, gcs, tmp_path
    finally:
        for p in (sim, proxy):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(5)
                except subprocess.TimeoutExpired:
                    p.kill()


def test_pymavlink_param_round_trip_through_the_cli(running: tuple[subprocess.Popen[bytes], int, Path]) -> None:
    proxy, gcs_port, tmp = running
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255, source_component=190)
    try:
        hb = gcs.wait_heartbeat(timeout=20)
        assert hb is not None, (tmp / "proxy.log").read_text()
        assert gcs.target_system == 1
        gcs.mav.param_request_list_send(1, 1)
        names: set[str] = set()
        count = None
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and (count is None or len(names) < count):
            msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None:
                names.add(msg.param_id)
                count = msg.param_count
        assert count is not None and len(names) == count and "MIS_TAKEOFF_ALT" in names
        gcs.mav.param_set_send(1, 1, b"MIS_TAKEOFF_ALT", 4.25, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
        deadline = time.monotonic() + 10
        value = None
        while time.monotonic() < deadline:
            msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None and msg.param_id == "MIS_TAKEOFF_ALT":
                value = msg.param_value
                break
        assert value == pytest.approx(4.25)
    finally:
        gcs.close()
    # The exchange can finish inside the first --stats-interval (0.5 s) on a quiet machine: wait for a stats line,
    # an event, rather than for a time.
    deadline = time.monotonic() + 10
    while "proxy.stats sysid=1" not in (tmp / "proxy.log").read_text() and time.monotonic() < deadline:
        time.sleep(0.1)
    code, took = stop(proxy, signal.SIGINT)
    assert code == 0 and took < 1.0, (code, took, (tmp / "proxy.log").read_text()[-2000:])
    log = (tmp / "proxy.log").read_text()
    assert "proxy.ready" in log and "proxy.stats sysid=1" in log and "proxy.stop" in log
    # the recording opens in pymavlink's tlog reader, both directions in it
    seen: dict[str, int] = {}
    for name in ("original.tlog", "forwarded.tlog"):
        mlog = mavutil.mavlink_connection(str(tmp / "rec" / "v1" / name))
        types: set[str] = set()
        n = 0
        while (m := mlog.recv_match()) is not None:
            types.add(m.get_type())
            n += 1
        assert {"HEARTBEAT", "PARAM_VALUE", "PARAM_SET", "PARAM_REQUEST_LIST"} <= types, (name, types)
        seen[name] = n
    # a few seconds of telemetry plus the parameter exchange; fewer frames on a loaded machine
    assert seen["original.tlog"] == seen["forwarded.tlog"] > 50


def test_sigterm_stops_within_a_second(running: tuple[subprocess.Popen[bytes], int, Path]) -> None:
    proxy, _gcs, tmp = running
    deadline = time.monotonic() + 30  # its handlers are in place once it says it is ready (slow on a busy machine)
    while b"proxy.ready" not in (tmp / "proxy.log").read_bytes() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)
    assert proxy.poll() is None, (tmp / "proxy.log").read_text()
    code, took = stop(proxy, signal.SIGTERM)
    assert code == 0 and took < 1.0, (code, took)


def test_port_taken_is_one_line_and_exit_1(udp_port: Callable[[], int]) -> None:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        out = subprocess.run([sys.executable, "-m", "mitm_proxy", "--broker", "none", "--vehicle",
                              f"udpin://127.0.0.1:{port}", "--ground", f"udpout://127.0.0.1:{udp_port()}"],
                             capture_output=True, text=True, timeout=20)  # fmt: skip
    assert out.returncode == 1
    assert out.stderr.strip().count("\n") == 0 and "cannot open a socket" in out.stderr, out.stderr

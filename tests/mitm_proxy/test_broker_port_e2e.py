"""``--broker-port`` on every command that talks to a broker, as processes on a free port (issue 36).

A newcomer on a shared host whose 1883 is someone else's starts ``secuav-proxy --broker-port N`` and points
the other commands at N; nobody runs the internal broker module. A proxy that finds a broker it did not start
says whose it is; ``secuav-attack apply --vehicle 7`` fails at once when the online records say no proxy
serves v7.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import aiomqtt
import pytest

from demos.cli import build_parser as demo_parser
from demos.cli import ports_of
from flightsim.companion.cli import build_parser as feed_parser
from flightsim.companion.cli import parse_config
from secuav_common.broker import port_in_use

pytestmark = [pytest.mark.timeout(120)]
REPO = Path(__file__).resolve().parents[2]


def attack(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mitm_proxy.tools.attack_cli", *argv], cwd=REPO,
                          capture_output=True, text=True, timeout=60)  # fmt: skip


def until(check: Callable[[], bool], what: str, limit_s: float = 20.0) -> None:
    deadline = time.monotonic() + limit_s
    while not check():
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", *args], cwd=REPO, stdout=log.open("wb"),
                            stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip


def stop(procs: list[subprocess.Popen[bytes]]) -> list[int | None]:
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    codes: list[int | None] = []
    for proc in procs:
        try:
            codes.append(proc.wait(10))
        except subprocess.TimeoutExpired:
            proc.kill()
            codes.append(None)
    return codes


@pytest.fixture
def first_proxy(tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]) -> Iterator[int]:
    """``secuav-proxy --broker-port N`` (its embedded broker on N), serving v1; yields N once it is online."""
    port = tcp_port()
    proc = spawn(["mitm_proxy", "--broker-port", str(port), "--instance", "first", "--vehicle",
                  f"udpin://127.0.0.1:{udp_port()}", "--ground", f"udpout://127.0.0.1:{udp_port()}"],
                 tmp_path / "first.log")  # fmt: skip
    try:
        until(lambda: b"mqtt.connected" in (tmp_path / "first.log").read_bytes(), "the first proxy online")
        yield port
    finally:
        assert stop([proc]) == [0], (tmp_path / "first.log").read_text()[-2000:]


def test_the_proxy_starts_its_broker_on_the_port_given_and_attack_finds_it_there(first_proxy: int) -> None:
    port = first_proxy
    assert port_in_use("127.0.0.1", port)
    done = attack("status", "--json", "--broker-port", str(port))
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["instances"]["first"]["vehicles"] == [1]
    # the same broker spelled as a URL without a port, plus --broker-port; a URL naming another port is refused
    assert attack("status", "--broker", "mqtt://127.0.0.1", "--broker-port", str(port)).returncode == 0
    clash = attack("status", "--broker", "mqtt://127.0.0.1:1", "--broker-port", str(port))
    assert clash.returncode == 2 and "names port 1 but --broker-port says" in clash.stderr, clash.stderr


def test_apply_to_a_vehicle_no_proxy_serves_says_so_from_the_online_records(first_proxy: int) -> None:
    done = attack("apply", "wall-spoof", "--vehicle", "7", "--broker-port", str(first_proxy), "--timeout", "5")
    assert done.returncode == 3
    # the online record's answer, not the 5 s wait's "no acknowledgement within 5 s"
    assert "v7: no proxy on the broker" in done.stderr and "(first serves v1)" in done.stderr, done.stderr
    assert "no acknowledgement" not in done.stderr
    served = attack("apply", "wall-spoof", "--vehicle", "1", "--broker-port", str(first_proxy))
    assert served.returncode == 0 and served.stdout.startswith("ok: v1 wall-spoof"), served.stderr


def test_a_second_proxy_and_a_console_on_that_port_say_whose_broker_they_share(
    first_proxy: int, tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> None:
    port = first_proxy
    second = spawn(["mitm_proxy", "--broker-port", str(port), "--instance", "second", "--vehicle",
                    f"udpin://127.0.0.1:{udp_port()}", "--ground", f"udpout://127.0.0.1:{udp_port()}"],
                   tmp_path / "second.log")  # fmt: skip
    console = spawn(["webconsole", "--broker-port", str(port), "--listen", f"127.0.0.1:{tcp_port()}"],
                    tmp_path / "console.log")  # fmt: skip
    try:
        until(lambda: b"proxy.ready" in (tmp_path / "second.log").read_bytes(), "the second proxy up")
        until(lambda: b"console.ready" in (tmp_path / "console.log").read_bytes(), "the console up")
    finally:
        codes = stop([second, console])
    for name in ("second.log", "console.log"):
        lines = [ln for ln in (tmp_path / name).read_text().splitlines() if "broker.reuse" in ln]
        assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0], (name, lines)
        assert 'users="proxy first (v1)' in lines[0], lines[0]  # whose it is, in the one line
    assert codes == [0, 0], codes


def test_the_simulator_publishes_truth_on_the_port_given(tmp_path: Path, tcp_port: Callable[[], int],
                                                          udp_port: Callable[[], int]) -> None:  # fmt: skip
    from secuav_common.broker import EmbeddedBroker

    port = tcp_port()

    async def run() -> dict[str, object]:
        async with EmbeddedBroker(port=port), aiomqtt.Client("127.0.0.1", port) as client:
            await client.subscribe("secuav/v1/truth")
            sim = spawn(["flightsim", "wall_hover", "--broker-port", str(port), "--mavlink",
                         f"udpout://127.0.0.1:{udp_port()}"], tmp_path / "sim.log")  # fmt: skip
            try:
                async with asyncio.timeout(30):
                    message = await anext(aiter(client.messages))
            finally:
                assert stop([sim]) in ([0], [130]), (tmp_path / "sim.log").read_text()[-2000:]
            return json.loads(bytes(message.payload))  # type: ignore[arg-type]

    truth = asyncio.run(run())
    assert truth["sysid"] == 1 and len(truth["pos_ned_m"]) == 3, truth  # type: ignore[arg-type]


def test_the_feed_and_the_demo_take_the_port_too() -> None:
    def feed(*argv: str) -> str:
        return parse_config(feed_parser().parse_args(["--to", "udpout://127.0.0.1:14600", *argv])).truth

    assert feed() == "mqtt://127.0.0.1"  # parse_broker_url: 1883
    assert feed("--broker-port", "18830") == "mqtt://127.0.0.1:18830"
    assert feed("--truth", "mqtt://lab.example", "--broker-port", "18830") == "mqtt://lab.example:18830"
    with pytest.raises(ValueError, match="not from a broker"):
        feed("--truth", "udpin://127.0.0.1:14700", "--broker-port", "18830")

    def demo(*argv: str) -> int:
        args: argparse.Namespace = demo_parser().parse_args(["wall-hover", *argv])
        return ports_of(args).mqtt

    assert demo() == 1883
    assert demo("--broker-port", "18830") == 18830
    assert demo("--base-port", "20000") == 20021 and demo("--base-port", "20000", "--broker-port", "18830") == 18830

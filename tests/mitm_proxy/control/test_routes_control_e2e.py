"""Routes changed at runtime, and the fleet view, against real ``secuav-proxy`` processes.

A pymavlink vehicle streams DISTANCE_SENSOR and ATTITUDE at 200 Hz each into
the daemon; a pymavlink ground station reads what comes out. ``secuav-attack
routes set`` (a real subprocess, over a real broker) denies ATTITUDE on that
ground endpoint and lifts it again, many times while the stream flows: every
DISTANCE_SENSOR frame still arrives (a swap drops nothing it should not), a
rejected set leaves the rules in force, and ``routes show``/``status`` name the
instance. A second proxy on the same broker shows up as its own instance.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import aiomqtt
import pytest
from pymavlink import mavutil

from secuav_common.broker import EmbeddedBroker
from tests.conftest import free_tcp_port
from tests.support.brokers import attack_cli

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(180), pytest.mark.usefixtures("proxy_path")]


def _proxy(broker: str, instance: str, vehicle: int, ground: int, log: Path, sysid: int) -> subprocess.Popen[bytes]:
    config = log.with_suffix(".yaml")  # the config file form of one link, with its sysid
    config.write_text(json.dumps({"links": [{"sysid": sysid, "vehicle": f"udpin://127.0.0.1:{vehicle}",
                                             "ground": [f"udpout://127.0.0.1:{ground}"]}]}))  # fmt: skip
    return subprocess.Popen(
        [sys.executable, "-m", "mitm_proxy", "--broker", broker, "--instance", instance, "--config", str(config)],
        stdout=log.open("wb"), stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip


def _stop(proc: subprocess.Popen[bytes]) -> int:
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()


class Stream:
    """Vehicle -> proxy -> ground at 200 Hz per message, counting what the ground receives."""

    def __init__(self, vehicle_port: int, gcs_port: int) -> None:
        self.veh = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle_port}", source_system=1, source_component=1)
        self.gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
        self.sent: Counter[str] = Counter()
        self.got: Counter[str] = Counter()
        self.counting = False
        self.sending = True
        self.seq = 0  # each pair of frames carries its number in time_boot_ms
        self.since = 0  # frames numbered below this are not counted (see mark())
        self.stop = asyncio.Event()

    async def run(self) -> None:
        while not self.stop.is_set():
            if self.sending:
                self.seq += 1
                self.veh.mav.distance_sensor_send(self.seq, 5, 4000, 250, 0, 0, 0, 0)
                self.veh.mav.attitude_send(self.seq, 0.1, 0.2, 0.3, 0, 0, 0)
                if self.counting:
                    self.sent.update(["DISTANCE_SENSOR", "ATTITUDE"])
            self.drain()
            await asyncio.sleep(0.005)

    def drain(self) -> None:
        while (msg := self.gcs.recv_match(blocking=False)) is not None:
            if self.counting and getattr(msg, "time_boot_ms", 0) > self.since:
                self.got[msg.get_type()] += 1

    def mark(self) -> None:
        """Count afresh from the next frame sent: one still in flight is not counted."""
        self.since = self.seq
        self.sent.clear()
        self.got.clear()

    async def settle(self, want: Callable[[], bool], limit_s: float = 20) -> None:
        async with asyncio.timeout(limit_s):
            while not want():
                await asyncio.sleep(0.05)

    async def window(self, seconds: float) -> Counter[str]:
        """What the ground got in the next ``seconds``."""
        before = self.got.copy()
        await asyncio.sleep(seconds)
        return self.got - before

    async def until_got(self, count: int, kind: str, limit_s: float = 20) -> Counter[str]:
        """What the ground got until ``count`` more ``kind`` frames arrived (counted, not timed: a loaded machine
        sends fewer than 200 a second)."""
        before = self.got.copy()
        await self.settle(lambda: self.got[kind] - before[kind] >= count, limit_s)
        return self.got - before

    def close(self) -> None:
        self.veh.close()
        self.gcs.close()


async def _until_rated(out: asyncio.StreamReader, row: str) -> str:
    """What ``status --watch`` printed, up to the first ``row`` whose "down in/s" cell is a number."""
    text = ""
    while line := (await out.readline()).decode():
        text += line
        cells = line.split()
        if line.startswith(row) and len(cells) > 5 and cells[5].replace(".", "", 1).isdigit():
            break
    return text


async def test_routes_set_show_and_the_fleet_view_with_real_proxies(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()
    broker = f"mqtt://127.0.0.1:{port}"
    vehicle, gcs = udp_port(), udp_port()
    ground = f"ground:{gcs}"
    async with EmbeddedBroker(port=port):
        proxy = _proxy(broker, "bench-a", vehicle, gcs, tmp_path / "a.log", sysid=1)
        other = _proxy(broker, "bench-b", udp_port(), udp_port(), tmp_path / "b.log", sysid=7)
        stream = Stream(vehicle, gcs)
        stream.counting = True
        task = asyncio.create_task(stream.run())
        try:
            await stream.settle(lambda: stream.got["ATTITUDE"] > 50)

            # Two instances: a route set must say which one.
            code, out = await attack_cli("routes", "set", ground, "deny=ATTITUDE", "--broker", broker)
            assert code == 2 and "2 proxies are online (bench-a, bench-b)" in out, out
            at_a = ("--instance", "bench-a", "--broker", broker)
            code, out = await attack_cli("routes", "set", ground, "deny=ATTITUDE", *at_a)
            assert code == 0 and out.strip() == f"ok: bench-a {ground} deny=ATTITUDE", out
            await asyncio.sleep(0.2)  # what was in flight
            seen = await stream.until_got(100, "DISTANCE_SENSOR")
            assert seen["ATTITUDE"] == 0, seen

            code, out = await attack_cli("routes", "show", *at_a)
            assert code == 0 and f"{ground}" in out and "deny=ATTITUDE" in out and "vehicle" in out, out

            # Rejected by the proxy (an endpoint it does not have): the rules in force stay.
            async with aiomqtt.Client("127.0.0.1", port) as client:
                await client.subscribe("secuav/proxy/bench-a/routes/state")
                bad = {"request_id": "bad", "endpoints": {"ground:1": None}}
                await client.publish("secuav/proxy/bench-a/routes/set", json.dumps(bad).encode())
                async with asyncio.timeout(10):
                    async for message in client.messages:
                        state = json.loads(message.payload)
                        if state.get("request_id") == "bad":
                            break
            assert not state["ok"] and "ground:1: no such endpoint" in state["error"]
            assert state["endpoints"][ground]["rules"] == {"down": {"deny": ["ATTITUDE"]}}
            assert (await stream.window(0.5))["ATTITUDE"] == 0

            # A typo fails here, before anything is sent.
            code, out = await attack_cli("routes", "set", ground, "deny=ATTITUDEX", *at_a)
            assert code == 1 and "ATTITUDEX" in out and "not a MAVLink message name" in out, out

            # Swap the rules back and forth while 200 Hz flows: no DISTANCE_SENSOR frame is lost to a swap.
            stream.mark()
            for i in range(6):
                rules = "none" if i % 2 == 0 else "deny=ATTITUDE"
                code, out = await attack_cli("routes", "set", ground, rules, *at_a)
                assert code == 0, out
            stream.sending = False  # what is in flight arrives and is counted
            await asyncio.sleep(0.5)
            stream.drain()
            assert stream.sent["DISTANCE_SENSOR"] > 400
            assert stream.got["DISTANCE_SENSOR"] == stream.sent["DISTANCE_SENSOR"], (stream.sent, stream.got)
            assert 0 < stream.got["ATTITUDE"] < stream.sent["ATTITUDE"]  # on for part of the time
            stream.sending = True

            # The fleet view: both instances and their vehicles.
            code, out = await attack_cli("status", "--broker", broker)
            assert code == 0, out
            assert "proxy bench-a: online" in out and "vehicles v1\n" in out and "vehicles v7\n" in out, out
            assert "proxy bench-b: online" in out and "v7: attack none" in out, out

            # status --watch: a live table until Ctrl-C, with the proxy's own frame rates.
            watch = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "mitm_proxy.tools.attack_cli", "status", "--watch", "--interval", "0.5",
                "--broker", broker, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
            )  # fmt: skip
            # Until v1's row shows a frame rate (it takes two stats messages, and the watcher's own start-up, which
            # is seconds on a loaded machine): a fixed 4 s left it at "-" in one parallel run.
            assert watch.stdout is not None
            head = await asyncio.wait_for(_until_rated(watch.stdout, "v1 "), 30)
            watch.send_signal(signal.SIGINT)
            out_b, _ = await asyncio.wait_for(watch.communicate(), 20)
            text = head + out_b.decode()
            assert watch.returncode == 0, text
            rows = [ln for ln in text.splitlines() if ln.startswith("v1 ")]
            assert rows and "Traceback" not in text, text
            assert rows[-1].split()[1] == "bench-a" and any(ln.startswith("v7 ") for ln in text.splitlines())
            rate = float(rows[-1].split()[5])  # down in/s: 400 frames/s offered
            assert 200 < rate < 600, rows[-1]
        finally:
            stream.stop.set()
            await task
            stream.close()
            codes = _stop(proxy), _stop(other)
        # The instance's record says offline after a clean stop.
        async with aiomqtt.Client("127.0.0.1", port) as client:
            await client.subscribe("secuav/proxy/+/online")
            records = {}
            async with asyncio.timeout(5):
                async for message in client.messages:
                    body = json.loads(message.payload)
                    records[body["instance"]] = body
                    if len(records) == 2:
                        break
        assert {k: v["online"] for k, v in records.items()} == {"bench-a": False, "bench-b": False}
    assert codes == (0, 0), (tmp_path / "a.log").read_text()

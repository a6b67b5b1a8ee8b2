"""The console's test bench, shared by the tests of tests/webconsole/: the API served by uvicorn on loopback
beside a real broker and the proxy's own control plane (``open_bench``), raw HTTP requests, and the processes and
browser helpers of the page tests. Fixtures built on these are in tests/webconsole/conftest.py."""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import uvicorn

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import ControlPlane
from mitm_proxy.control.secure import SecureSwitch
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.broker import BrokerAddress, EmbeddedBroker
from secuav_common.scenario import load_scenario
from tests.conftest import free_tcp_port
from webconsole.api import build_app
from webconsole.connections import server_config
from webconsole.fleet import Fleet, Session


def fake_stats() -> dict[int, dict[str, Any]]:
    return {1: {"downlink": {"frames_in": 10, "frames_out": 10}, "uplink": {}, "latency_ms": {"p50": 0.2}}}


@dataclass
class Bench:
    base: str
    fleet: Fleet
    slots: dict[int, AttackSlot]
    plane: ControlPlane


def call(base: str, path: str, body: Any = None, auth: str | None = None) -> tuple[int, Any]:
    """One HTTP request (in a worker thread: the server runs on this test's loop)."""
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(base + path, data=data, method="GET" if body is None else "POST")
    if data is not None:
        request.add_header("Content-Type", "application/json")
    if auth:
        request.add_header("Authorization", auth)
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read() or b"null")
    except urllib.error.HTTPError as exc:
        raw = exc.read()
        try:
            return exc.code, json.loads(raw)
        except ValueError:
            return exc.code, raw.decode()


@contextlib.asynccontextmanager
async def serve(fleet: Fleet, session: Session, password: str | None = None, **options: Any) -> AsyncIterator[str]:
    port = free_tcp_port()
    served = {k: options.pop(k) for k in ("trusted_proxies", "limits") if k in options}
    app = build_app(fleet, session, password, ack_timeout_s=2.0, **options)
    server = uvicorn.Server(server_config(app, "127.0.0.1", port, **served))  # as secuav-console serves it
    server.install_signal_handlers = lambda: None  # type: ignore[method-assign]
    task = asyncio.create_task(server.serve())
    while not server.started:
        await asyncio.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        await task


@contextlib.asynccontextmanager
async def open_bench(secure: dict[int, SecureSwitch] | None = None) -> AsyncIterator[Bench]:
    port = free_tcp_port()
    slots = {1: AttackSwitch(AttackSlot(1))}
    async with EmbeddedBroker(port=port):
        url = f"mqtt://127.0.0.1:{port}"
        controls = vehicle_controls("lab", slots, {1: AttackStage(slots[1].slot)}, secure)
        plane = ControlPlane(url, controls, stats=fake_stats)
        fleet = Fleet([load_scenario("wall_hover")])
        session = Session(BrokerAddress("127.0.0.1", port), fleet, "http://test/")
        mqtt = asyncio.create_task(session.run())
        async with plane, serve(fleet, session) as base:
            await plane.wait_connected(10)
            await asyncio.wait_for(session.connected.wait(), 10)
            for _ in range(100):  # the retained states, then one stats message
                if 1 in fleet.vehicles and fleet.summary()[0]["online"]:
                    break
                await asyncio.sleep(0.1)
            yield Bench(base, fleet, slots, plane)
        mqtt.cancel()


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


CHROMEDRIVER = shutil.which("chromedriver")


BAD_PROFILE = """name: typo
rules:
  - target: {message: DISTANCE_SENSOR, sensor_id: 0, field: current_distance}
    kind: bias
    offset_m: banana
"""


def paste_profile(driver: Any, text: str) -> Any:
    """Paste ``text`` into the page's custom-profile box and apply it, as a user does; the page's error element."""
    from selenium.webdriver.common.by import By

    driver.find_element(By.CSS_SELECTOR, "#custom summary").click()
    area = driver.find_element(By.ID, "yaml")
    area.clear()
    area.send_keys(text)
    driver.find_element(By.ID, "apply-yaml").click()
    return driver.find_element(By.ID, "yaml-error")


def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", *args], stdout=log.open("wb"), stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip


def stop_all(procs: list[subprocess.Popen[bytes]]) -> list[int | None]:
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    codes = []
    for proc in procs:
        try:
            codes.append(proc.wait(10))
        except subprocess.TimeoutExpired:
            proc.kill()
            codes.append(None)
    return codes


@dataclass
class Services:
    """The real services of a page test (:func:`console_services`): their ports and processes, and the processes'
    exit codes once stopped."""

    tmp_path: Path
    port: int  # the broker's
    web: int  # the console's
    vehicle: int  # where the proxy listens for the vehicle
    gcs_port: int  # where the proxy sends to the ground
    procs: list[subprocess.Popen[bytes]]
    codes: list[int | None] | None = None

    @property
    def broker(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    async def console_up(self) -> None:
        await until(lambda: b"console.ready" in (self.tmp_path / "console.log").read_bytes(), 30, "console up")


@contextlib.asynccontextmanager
async def console_services(
    tmp_path: Path,
    udp_port: Any,
    *,
    proxy_args: tuple[str, ...] = (),
    flightsim: bool = True,
    flightsim_on_broker: bool = False,
) -> AsyncIterator[Services]:
    """A real broker, then ``secuav-proxy`` (``p.log``; ``proxy_args`` after its instance name), ``secuav-sim
    wall_hover`` sending to it (``sim.log``; on the broker too with ``flightsim_on_broker``) unless not
    ``flightsim``, and ``secuav-console --scenario wall_hover`` (``console.log``), in that order; on exit the
    processes are stopped (``codes``), then the broker."""
    port, web = free_tcp_port(), free_tcp_port()
    vehicle, gcs_port = udp_port(), udp_port()
    services = Services(tmp_path, port, web, vehicle, gcs_port, [])
    broker = services.broker
    async with EmbeddedBroker(port=port):
        procs = services.procs
        procs.append(spawn(["mitm_proxy", "--broker", broker, "--instance", "bench", *proxy_args, "--vehicle",
                            f"udpin://127.0.0.1:{vehicle}", "--ground", f"udpout://127.0.0.1:{gcs_port}"],
                           tmp_path / "p.log"))  # fmt: skip
        if flightsim:
            on_broker = ["--broker", broker] if flightsim_on_broker else []
            procs.append(spawn(["flightsim", "wall_hover", "--mavlink", f"udpout://127.0.0.1:{vehicle}", *on_broker],
                               tmp_path / "sim.log"))  # fmt: skip
        procs.append(spawn(["webconsole", "--broker", broker, "--listen", f"127.0.0.1:{web}", "--scenario",
                            "wall_hover"], tmp_path / "console.log"))  # fmt: skip
        try:
            yield services
        finally:
            services.codes = stop_all(procs)


async def until(check: object, limit_s: float, what: str) -> None:
    deadline = time.monotonic() + limit_s
    while not check():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {limit_s} s")
        await asyncio.sleep(0.1)


def raw(base: str, method: str, path: str, body: bytes = b"", headers: dict[str, str] | None = None,
        ) -> tuple[int, dict[str, str], bytes]:  # fmt: skip
    """One request with exactly the headers given (http.client adds only Host and Content-Length)."""
    host, port = base.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        conn.request(method, path, body=body or None, headers=headers or {})
        response = conn.getresponse()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    finally:
        conn.close()


def open_stream(base: str) -> tuple[int, http.client.HTTPConnection]:
    host, port = base.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    conn.request("GET", "/api/stream?vehicle=1")
    return conn.getresponse().status, conn


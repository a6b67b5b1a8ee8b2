"""Fixtures of the console's tests: the served API and control plane (``bench``, ``secure_bench``), a headless
chromium (``browser``) and a page of another origin (``hostile_page``); their helpers are in
tests/support/console.py."""

from __future__ import annotations

import http.server
import os
import threading
from collections.abc import AsyncIterator, Iterator

import pytest

from mitm_proxy.control.secure import SecureSwitch
from mitm_proxy.stages.secure.stage import OFF, SecureStage
from secuav_common.scenario import load_scenario
from tests.conftest import free_tcp_port
from tests.support.console import CHROMEDRIVER, CHROMIUM, Bench, open_bench


@pytest.fixture
async def bench() -> AsyncIterator[Bench]:
    async with open_bench() as b:
        yield b


@pytest.fixture
async def secure_bench() -> AsyncIterator[Bench]:
    """The bench with a real secure stage on vehicle 1 (the wall scenario's rangefinder group)."""
    slot = SecureSwitch(SecureStage(OFF, load_scenario("wall_hover"), 1))
    try:
        async with open_bench({1: slot}) as b:
            yield b
    finally:
        slot.close()


@pytest.fixture
def browser() -> Iterator[object]:
    if CHROMIUM is None or CHROMEDRIVER is None:
        if os.environ.get("CI"):  # .ci/run installs them: missing there is a setup bug, not a reason to skip
            pytest.fail("chromium and chromium-driver are not installed, but CI must test the page in a browser")
        pytest.skip("chromium and chromium-driver are not installed (apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1400,1200"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def hostile_page() -> Iterator[tuple[int, list[str]]]:
    """A plain HTTP server on another loopback port: another origin, as any page the operator visits."""
    pages: list[str] = [""]

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = pages[0].encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    port = free_tcp_port()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield port, pages
    finally:
        server.shutdown()
        server.server_close()


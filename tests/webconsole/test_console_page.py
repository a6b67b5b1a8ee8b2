"""The console's page in a real chromium, as a crew uses it (issue 36): a fleet row is selected by a press of
any length while the table is rebuilt 12.5 times a second, no green "live" badge shows without a broker, and
a page on another origin cannot take the event-stream slots with HEAD requests.

The app is the real one over uvicorn on loopback; the vehicles' proxy records
and stats come over a real embedded broker.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any

import aiomqtt
import pytest

from secuav_common.broker import BrokerAddress, EmbeddedBroker
from tests.conftest import free_tcp_port
from tests.support.console import serve
from webconsole.api import StreamSlots
from webconsole.fleet import Fleet, Session

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


async def _wait(driver: Any, check: Callable[[Any], bool], limit_s: float, what: str) -> None:
    deadline = time.monotonic() + limit_s
    while not await asyncio.to_thread(check, driver):
        assert time.monotonic() < deadline, f"{what}: not within {limit_s} s"
        await asyncio.sleep(0.1)


def _press(driver: Any, sysid: int, hold_s: float) -> None:
    """Press a fleet row where it is on the screen, hold it ``hold_s``, release (a hand on a trackpad). By
    position, not by element: the row element is replaced with every update, which is the point."""
    from selenium.webdriver.common.actions.action_builder import ActionBuilder

    x, y = driver.execute_script(
        f'const r = document.querySelector(\'#fleet tbody tr[data-sysid="{sysid}"]\').getBoundingClientRect();'
        "return [Math.round(r.left + 10), Math.round(r.top + r.height / 2)];"
    )
    actions = ActionBuilder(driver)
    actions.pointer_action.move_to_location(x, y).pointer_down().pause(hold_s).pointer_up()
    actions.perform()


def _title(driver: Any) -> str:
    return str(driver.execute_script("return document.getElementById('vehicle-title').textContent"))


async def test_a_fleet_row_held_150_ms_is_selected(browser: Any) -> None:
    """The review: with several vehicles, 0 of 9 clicks held 100 ms selected their row."""
    port = free_tcp_port()
    async with EmbeddedBroker(port=port):
        fleet = Fleet([])
        session = Session(BrokerAddress("127.0.0.1", port), fleet, "http://test/")
        mqtt = asyncio.create_task(session.run())
        await asyncio.wait_for(session.connected.wait(), 10)
        async with aiomqtt.Client("127.0.0.1", port) as proxy:
            record = {"instance": "lab", "online": True, "since": time.time(), "vehicles": [1, 2, 3, 4]}
            await proxy.publish("secuav/proxy/lab/online", json.dumps(record), qos=1, retain=True)
            for sysid in (1, 2, 3, 4):
                await proxy.publish(f"secuav/v{sysid}/stats", json.dumps({"downlink": {}}), qos=1)
        try:
            async with serve(fleet, session) as base:
                await asyncio.to_thread(browser.get, base + "/")
                rows = "return document.querySelectorAll('#fleet tbody tr').length"
                await _wait(browser, lambda d: d.execute_script(rows) == 4, 20, "four fleet rows")
                picked = []
                for sysid in (3, 2, 4, 1, 3, 4, 2, 1, 4):  # nine presses, as the review's
                    await asyncio.to_thread(_press, browser, sysid, 0.15)
                    await _wait(browser, lambda d, s=sysid: _title(d).startswith(f"Vehicle v{s}:"), 5,
                                f"v{sysid} selected")  # fmt: skip
                    picked.append(sysid)
                assert len(picked) == 9
        finally:
            mqtt.cancel()
            await asyncio.gather(mqtt, return_exceptions=True)


async def test_without_a_broker_the_page_says_so_and_shows_no_live_badge(browser: Any) -> None:
    """The review: with no broker reachable the page showed a green "live" badge and "No vehicle yet"."""
    dead = free_tcp_port()  # nothing listens there
    fleet = Fleet([])
    session = Session(BrokerAddress("127.0.0.1", dead), fleet, "http://test/", backoff_s=(0.2, 0.5))
    mqtt = asyncio.create_task(session.run())
    try:
        async with serve(fleet, session) as base:
            await asyncio.to_thread(browser.get, base + "/")
            badge = "return document.getElementById('link-state').textContent"
            await _wait(browser, lambda d: d.execute_script(badge) == "no broker", 20, "the badge says no broker")
            await asyncio.sleep(1.0)  # a dozen updates later it still does
            assert await asyncio.to_thread(browser.execute_script, badge) == "no broker"
            hint = "return document.getElementById('fleet-empty').textContent"
            text = await asyncio.to_thread(browser.execute_script, hint)
            assert f"127.0.0.1:{dead}" in text and "Not connected" in text, text
            classes = "return document.getElementById('link-state').className"
            assert "on" not in (await asyncio.to_thread(browser.execute_script, classes)).split()
    finally:
        mqtt.cancel()
        await asyncio.gather(mqtt, return_exceptions=True)


async def test_head_requests_from_another_origin_take_no_stream_slot(
    browser: Any,
    hostile_page: tuple[int, list[str]],
) -> None:
    """The review: four no-cors HEAD fetches from a page on another origin locked the operator's stream out."""
    port, pages = hostile_page
    fleet = Fleet([])
    session = Session(BrokerAddress("127.0.0.1", free_tcp_port()), fleet, "http://test/")
    slots = StreamSlots(per_client=4, total=32)
    async with serve(fleet, session, streams=slots) as base:
        pages[0] = f"""<!doctype html><html><body><script>
Promise.all([1, 2, 3, 4, 5, 6].map(() => fetch("{base}/api/stream?vehicle=1", {{method: "HEAD", mode: "no-cors"}})
  .catch(() => null))).then(() => {{ document.title = "sent"; }});
</script></body></html>"""
        await asyncio.to_thread(browser.get, f"http://127.0.0.1:{port}/")
        await _wait(browser, lambda d: d.title == "sent", 20, "the hostile page's HEADs sent")
        assert not slots.open, slots.open
        await asyncio.to_thread(browser.get, base + "/")  # the operator's own page gets its stream
        badge = "return document.getElementById('link-state').textContent"
        await _wait(browser, lambda d: d.execute_script(badge) in ("no broker", "live"), 20, "the page's stream")

"""The console's page in a real browser (Debian's chromium through selenium), against real services.

``secuav-sim`` flies nothing here: its vehicle sits at home and streams its
sensors to a real ``secuav-proxy``, which forwards to a pymavlink ground
station; ``secuav-console`` serves the page; all talk over a real broker on
loopback. The page must show the vehicle online within 5 s, a library profile
applied from its form must change what the ground station receives, a bad
pasted profile must show the field error without anything reaching the
broker's ``attack/set``, and the browser's console must stay free of errors.
"""

from __future__ import annotations

import asyncio
import json
import socket
import time
from pathlib import Path

import aiomqtt
import pytest
from pymavlink import mavutil

from mavframe import tlog
from tests.support.console import BAD_PROFILE, console_services, paste_profile, until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _sensor0_cm(gcs: mavutil.mavfile, seconds: float) -> list[int]:
    """Sensor 0's valid readings the ground station received over the next ``seconds`` (the backlog dropped).

    The simulated rangefinder drops samples as real ones do, sending them as "no target" (beyond
    ``max_distance``, PX4's convention): those say nothing about the range and are left out."""
    while gcs.recv_match(blocking=False) is not None:
        pass
    out, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        msg = gcs.recv_match(type="DISTANCE_SENSOR", blocking=True, timeout=0.2)
        if msg is not None and msg.id == 0 and msg.min_distance <= msg.current_distance <= msg.max_distance:
            out.append(msg.current_distance)
    return out


async def test_the_page_shows_steers_and_refuses_as_a_user_sees_it(
    browser: object, tmp_path: Path, udp_port: object
) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver = browser
    async with console_services(tmp_path, udp_port, flightsim_on_broker=True) as services:
        port, web = services.port, services.web
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{services.gcs_port}", source_system=255)
        sets: list[str] = []
        try:
            await services.console_up()
            baseline = await asyncio.to_thread(_sensor0_cm, gcs, 1.0)
            assert baseline and all(450 < v < 550 for v in baseline), baseline  # 5 m to the wall

            started = time.monotonic()
            driver.get(f"http://127.0.0.1:{web}/")  # type: ignore[attr-defined]

            def online() -> bool:  # read in one script: the table is redrawn ten times a second
                cells = driver.execute_script(  # type: ignore[attr-defined]
                    "return [...document.querySelectorAll('#fleet tbody tr td')].map(td => td.textContent)")
                return len(cells) > 3 and cells[0] == "v1" and cells[1] == "bench" and cells[2] == "online"

            await until(online, 30, "vehicle v1 online on the page")  # a deadline; the time is printed below
            shown_after_s = time.monotonic() - started

            # Apply a library profile from its parameter form.
            Select(driver.find_element(By.ID, "library")).select_by_value("distance-wrong")  # type: ignore[attr-defined]
            for name, value in (("sensors", "[0]"), ("start_s", "0"), ("factor", "1.5")):
                field = driver.find_element(By.CSS_SELECTOR, f"#params input[name='{name}']")  # type: ignore[attr-defined]
                field.clear()
                field.send_keys(value)
            driver.find_element(By.ID, "apply-library").click()  # type: ignore[attr-defined]
            ack = driver.find_element(By.ID, "ack")  # type: ignore[attr-defined]
            await until(lambda: "attack distance-wrong: ok" in ack.text, 30, "the proxy's acknowledgement")
            title = driver.find_element(By.ID, "vehicle-title")  # type: ignore[attr-defined]
            await until(lambda: "changing frames toward the ground" in title.text, 30, "the profile's direction")
            await asyncio.sleep(0.3)
            attacked = await asyncio.to_thread(_sensor0_cm, gcs, 1.0)
            assert attacked and all(700 < v < 800 for v in attacked), attacked  # 5 m * 1.5 on the ground

            # The secure stage's form: a plugin estimator with its declared parameters, defaults and ranges.
            Select(driver.find_element(By.ID, "estimator")).select_by_value("huber")  # type: ignore[attr-defined]
            huber_k = driver.find_element(By.CSS_SELECTOR, "#estimator-params input[name='huber_k']")  # type: ignore[attr-defined]
            assert huber_k.get_attribute("value") == "1.345"
            assert "in [0.5, 5]" in huber_k.find_element(By.XPATH, "..").text
            assert "secuav-example-plugin" in driver.find_element(By.ID, "estimator-summary").text  # type: ignore[attr-defined]

            # A bad pasted profile: the field error on the page, nothing on the broker's attack/set.
            async with aiomqtt.Client("127.0.0.1", port) as spy:
                await spy.subscribe("secuav/v1/attack/set")

                async def collect() -> None:
                    async for message in spy.messages:
                        if str(message.topic) == "secuav/v1/attack/set":  # amqtt also replays other retained topics
                            sets.append(bytes(message.payload).decode())  # type: ignore[arg-type]

                collector = asyncio.create_task(collect())
                error = paste_profile(driver, BAD_PROFILE)
                await until(lambda: error.is_displayed() and "rules[0]" in error.text, 30, "the field error")
                assert "banana" in error.text and error.get_attribute("data-field").startswith("rules[0]")
                await asyncio.sleep(1.0)
                collector.cancel()
            assert sets == [], sets
            still = await asyncio.to_thread(_sensor0_cm, gcs, 0.5)
            assert still and all(700 < v < 800 for v in still)  # the applied profile stays
            # flightsim never sends RANGEFINDER: no true-copy warning on the page (issue 36)
            box = driver.find_element(By.ID, "vehicle-warnings")  # type: ignore[attr-defined]
            assert "true_copy" not in (box.get_attribute("textContent") or "") and not box.is_displayed()

            # The page draws: a plot per sensor seen, the top view, no errors in the browser's console.
            await until(lambda: len(driver.find_elements(By.CSS_SELECTOR, "#plots .plot")) >= 1, 30, "plots")  # type: ignore[attr-defined]
            logged = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]  # type: ignore[attr-defined]
            script_errors = [e for e in logged if e["source"] != "network"]
            assert script_errors == [], script_errors
            # The only failed request is the refused profile (Chrome logs every 4xx answer it gets).
            refused = [("/api/vehicles/1/attack" in e["message"] and "422" in e["message"]) for e in logged]
            assert refused == [True], logged
        finally:
            gcs.close()
    codes = services.codes
    assert codes == [0, 0, 0] or all(c in (0, 130) for c in codes), [
        (p, (tmp_path / p).read_text()[-2000:]) for p in ("p.log", "sim.log", "console.log")
    ]
    print(json.dumps({"online_on_page_s": round(shown_after_s, 2)}))


async def test_the_page_shows_why_the_secure_stage_cannot_work(
    browser: object, tmp_path: Path, udp_port: object
) -> None:
    """A real proxy with ``--scenario wall_hover --secure secekf`` gets the recorded ArduPilot stream (downward
    rangefinders 0-2, tests/data): the page marks the vehicle's row and shows ``secure.layout_mismatch`` above its
    view (issue 27, item 2)."""
    driver = browser
    recorded = tlog.TlogReader((Path(__file__).resolve().parents[1] / "data/ardupilot-copter-guided.tlog").read_bytes())
    frames = [e.raw for e in recorded if e.header.sysid == 1][2000:4000]  # after boot: rangefinders streaming

    async def stream(stop: asyncio.Event, vehicle: int) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            while not stop.is_set():
                for i in range(0, len(frames), 20):  # about 400 frames a second, the recording's own rate
                    sock.sendto(b"".join(frames[i : i + 20]), ("127.0.0.1", vehicle))
                    await asyncio.sleep(0.05)
                    if stop.is_set():
                        return
        finally:
            sock.close()

    proxy_args = ("--scenario", "wall_hover", "--secure", "secekf")
    async with console_services(tmp_path, udp_port, proxy_args=proxy_args, flightsim=False) as services:
        stop = asyncio.Event()
        sender = asyncio.create_task(stream(stop, services.vehicle))
        try:
            await services.console_up()
            driver.get(f"http://127.0.0.1:{services.web}/")  # type: ignore[attr-defined]

            def shown() -> list[str]:
                return driver.execute_script(  # type: ignore[attr-defined, no-any-return]
                    "return [...document.querySelectorAll('#vehicle-warnings li')].map(li => li.textContent)")

            await until(lambda: any("secure.layout_mismatch" in w for w in shown()), 30, "the warning on the page")
            (text,) = shown()
            assert "0-4 forward (0)" in text and "down (25)" in text, text
            badge = driver.execute_script(  # one script: the table is redrawn ten times a second
                "const b = document.querySelector('#fleet tbody tr .badge.warning');"
                "return b ? [b.textContent, b.title] : null")  # type: ignore[attr-defined]
            assert badge is not None and badge[0] == "warning" and "secure.layout_mismatch" in badge[1], badge
            logged = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]  # type: ignore[attr-defined]
            assert logged == [], logged
        finally:
            stop.set()
            await sender
    codes = services.codes
    proxy_log = (tmp_path / "p.log").read_text()
    assert proxy_log.count("WARNING secure.layout_mismatch ") == 1, proxy_log[-3000:]  # the event, once
    assert all(c in (0, 130) for c in codes), codes

"""The console's smaller items from issue 36, in a real browser against real services.

``secuav-sim wall_hover`` streams its six rangefinders through a real ``secuav-proxy``; ``secuav-console
--scenario wall_hover`` serves the page. On it: the radar (sensor 4, one of the five the vehicle holds on) is
plotted from the start; a bad pasted profile's error names its field once, and goes once a later action
succeeds; after Clear the attack drop-down shows no profile, also when another operator clears.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.console import BAD_PROFILE, console_services, paste_profile, until

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


async def test_radar_ticked_error_said_once_and_cleared_and_clear_empties_the_drop_down(
    browser: object,
    tmp_path: Path,
    udp_port: object,
) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver = browser
    async with console_services(tmp_path, udp_port) as services:
        broker = services.broker
        await services.console_up()
        driver.get(f"http://127.0.0.1:{services.web}/")  # type: ignore[attr-defined]

        def ticked() -> dict[str, bool]:
            return driver.execute_script(  # type: ignore[attr-defined, no-any-return]
                "const o = {}; for (const b of document.querySelectorAll('#sensor-picker input'))"
                " o[b.dataset.sensor] = b.checked; return o")

        await until(lambda: len(ticked()) == 6, 15, "all six sensors in the picker")
        # the five the vehicle holds on (0-4, the radar is 4) are plotted; the downward laser is not
        assert ticked() == {"0": True, "1": True, "2": True, "3": True, "4": True, "5": False}, ticked()

        library = Select(driver.find_element(By.ID, "library"))  # type: ignore[attr-defined]
        assert library.first_selected_option.get_attribute("value") == ""  # nothing in force yet

        # A bad pasted profile: its field named once, not "field: source: field: ..."
        error = paste_profile(driver, BAD_PROFILE)
        await until(lambda: error.is_displayed() and "banana" in error.text, 10, "the field error")
        field = error.get_attribute("data-field")
        assert field and field.startswith("rules[0]") and error.text.count(field) == 1, error.text

        # A later success (a library profile) takes the stale error away.
        library.select_by_value("distance-wrong")
        driver.find_element(By.ID, "apply-library").click()  # type: ignore[attr-defined]
        ack = driver.find_element(By.ID, "ack")  # type: ignore[attr-defined]
        await until(lambda: "attack distance-wrong: ok" in ack.text, 10, "the proxy's acknowledgement")
        assert not error.is_displayed() and error.text == ""

        # Clear: the drop-down shows no profile (and the parameter form is empty).
        driver.find_element(By.ID, "clear-attack").click()  # type: ignore[attr-defined]
        await until(lambda: "attack cleared: ok" in ack.text, 10, "the clear acknowledged")
        assert library.first_selected_option.get_attribute("value") == ""
        assert driver.find_elements(By.CSS_SELECTOR, "#params input") == []  # type: ignore[attr-defined]

        # Another operator applies, then clears, from the command line: the drop-down follows both.
        def attack(*argv: str) -> subprocess.CompletedProcess[str]:
            return subprocess.run([sys.executable, "-m", "mitm_proxy.tools.attack_cli", *argv, "--broker", broker],
                                  capture_output=True, text=True, timeout=30)  # fmt: skip

        done = await asyncio.to_thread(attack, "apply", "distance-stuck")
        assert done.returncode == 0, done.stderr
        selected = lambda: library.first_selected_option.get_attribute("value")  # noqa: E731
        await until(lambda: selected() == "distance-stuck", 10, "the drop-down shows the profile in force")
        done = await asyncio.to_thread(attack, "clear")
        assert done.returncode == 0, done.stderr
        await until(lambda: selected() == "", 10, "the drop-down shows no profile after a clear elsewhere")

        logged = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]  # type: ignore[attr-defined]
        assert [e for e in logged if e["source"] != "network"] == [], logged
    codes = services.codes
    logs = [(p, (tmp_path / p).read_text()[-2000:]) for p in ("p.log", "console.log")]
    assert all(c in (0, 130) for c in codes), logs

"""The console and the watch view show a switch they were never told about, without naming it.

This module declares a ``note`` switch (its wire contract, as a new
``secuav_common/controlplane/switches/note.py`` would, and its proxy side, as a new
``mitm_proxy/control/note.py`` would), registers each for the test only, runs the real proxy (in-process,
two links on loopback UDP) and the real console app (uvicorn, its MQTT session) on a real embedded broker,
and checks that ``GET /api/vehicles`` carries the note's state in each row's ``switches``,
that ``POST /api/vehicles/{sysid}/switches/note`` sets it through the proxy (and what is refused where),
that ``secuav-attack status --watch`` draws a ``note`` column, and that the page (in chromium) lists the
note in the vehicle's panel and sets it.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from pydantic import BaseModel, ConfigDict, Field

from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.control import switches as proxy_side
from mitm_proxy.control.link import SwitchHost
from mitm_proxy.control.switch import Switch
from mitm_proxy.tools.board import Board
from mitm_proxy.tools.watch import COLUMNS, Rates, table
from secuav_common.broker import BrokerAddress, EmbeddedBroker
from secuav_common.controlplane import switches
from secuav_common.controlplane.contract import SwitchContract
from tests.support.console import call, raw, serve
from webconsole.fleet import Fleet, Session

pytestmark = pytest.mark.timeout(60)

SHOUTING = "note.shouting: the note is all capitals"


# -- the switch, as its own module would declare it ------------------------------------------------------


class NoteRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    text: str = Field(max_length=40)
    request_id: str | None = None


class NoteState(BaseModel):
    model_config = ConfigDict(extra="allow")
    sysid: int
    text: str | None = None
    since: float | None = None
    warnings: list[str] = []
    request_id: str | None = None
    ok: bool = True
    error: str | None = None


CONTRACT = SwitchContract(kind="note", scope="vehicle", state_model=NoteState, request_model=NoteRequest)


class NoteSwitch(Switch[NoteState]):
    contract = CONTRACT

    def __init__(self, sysid: int) -> None:
        super().__init__()
        self.sysid = sysid
        self.text: str | None = None
        self._since: float | None = None

    @classmethod
    def build(cls, host: SwitchHost, sysid: int | None) -> NoteSwitch | None:
        return None if sysid is None else cls(sysid)

    def apply(self, payload: Any, source: str) -> None:
        assert isinstance(payload, NoteRequest)
        self.text, self._since = payload.text, time.time()

    def current(self) -> dict[str, Any]:
        warnings = [SHOUTING] if self.text is not None and self.text.isupper() else []
        return {"sysid": self.sysid, "text": self.text, "since": self._since, "warnings": warnings}


# -- the bench ------------------------------------------------------------------------------------------


@pytest.fixture
def note_switch() -> Iterator[SwitchContract]:
    switches.register(CONTRACT)
    proxy_side.register(NoteSwitch)
    try:
        yield CONTRACT
    finally:
        proxy_side.unregister(CONTRACT.kind)
        switches.unregister(CONTRACT.kind)


@dataclass
class Bench:
    base: str
    fleet: Fleet
    proxy: Proxy


@pytest.fixture
async def bench(
    note_switch: SwitchContract, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> AsyncIterator[Bench]:
    """The real proxy and the real console on one embedded broker, the console's fleet holding both vehicles."""
    port = tcp_port()
    links = [LinkConfig(sysid=s, vehicle=f"udpin://127.0.0.1:{udp_port()}",
                        ground=[f"udpout://127.0.0.1:{udp_port()}"]) for s in (1, 2)]  # fmt: skip
    config = ProxyConfig(links=links, broker=f"mqtt://127.0.0.1:{port}", instance="lab")
    async with EmbeddedBroker(port=port), Proxy(config) as proxy:
        assert proxy.control is not None
        await proxy.control.wait_connected(10)
        fleet = Fleet()
        session = Session(BrokerAddress("127.0.0.1", port), fleet, "http://test/")
        mqtt = asyncio.create_task(session.run())
        try:
            async with serve(fleet, session) as base:
                await asyncio.wait_for(session.connected.wait(), 10)
                await until(lambda: [r["sysid"] for r in fleet.summary()] == [1, 2]
                            and all(r["switches"]["note"] is not None for r in fleet.summary()))  # fmt: skip
                yield Bench(base, fleet, proxy)
        finally:
            mqtt.cancel()


async def until(check: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.05)


def row(fleet: Fleet, sysid: int) -> dict[str, Any]:
    return next(r for r in fleet.summary() if r["sysid"] == sysid)


# -- the proof ------------------------------------------------------------------------------------------


async def test_the_rows_carry_every_declared_switch_and_the_console_sets_the_new_one(bench: Bench) -> None:
    status, rows = await asyncio.to_thread(call, bench.base, "/api/vehicles")
    assert status == 200 and [r["sysid"] for r in rows] == [1, 2]
    assert list(rows[0]["switches"]) == ["attack", "attack/mode", "note", "secure"]  # the registry's order
    first = rows[0]["switches"]["note"]  # published, retained, at connect
    assert first == {"sysid": 1, "text": None, "since": None, "warnings": [], "request_id": None, "ok": True,
                     "error": None}  # fmt: skip
    assert rows[0]["switches"]["attack/mode"]["mode"] == "on" and rows[0]["mode"] == "on"  # the old fields stay
    assert rows[0]["switches"]["attack"]["profile"] is None and rows[0]["profile"] is None

    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/2/switches/note", {"text": "LOW BATTERY"})
    assert status == 200 and ack["ok"] and ack["text"] == "LOW BATTERY" and ack["sysid"] == 2, ack
    assert ack["request_id"].startswith("console-")
    assert bench.proxy.control is not None
    assert bench.proxy.control.controls.vehicle(2, "note").text == "LOW BATTERY"  # type: ignore[union-attr]
    assert bench.proxy.control.controls.vehicle(1, "note").text is None  # type: ignore[union-attr]
    await until(lambda: (row(bench.fleet, 2)["switches"]["note"] or {}).get("text") == "LOW BATTERY")
    status, rows = await asyncio.to_thread(call, bench.base, "/api/vehicles")
    note = rows[1]["switches"]["note"]
    assert note["text"] == "LOW BATTERY" and note["warnings"] == [SHOUTING] and note["ok"]
    assert rows[0]["switches"]["note"]["text"] is None
    assert rows[1]["warnings"] == []  # the row's own warnings stay those of attack/state and secure/state

    # Refused by the console, by the request model the switch declares: nothing is sent (422, the field).
    status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/2/switches/note", {"text": "x" * 41})
    assert status == 422 and answer["field"] == "text" and "at most 40 characters" in answer["error"], answer
    status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/2/switches/note", ["text"])
    assert status == 422 and "valid dictionary" in answer["error"], answer
    await asyncio.sleep(0.3)
    assert bench.proxy.control.controls.vehicle(2, "note").text == "LOW BATTERY"  # type: ignore[union-attr]

    # A request id in the body is the console's to give: the body's is dropped, the acknowledgement still comes.
    body = {"text": "quiet now", "request_id": "mine"}
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/switches/note", body)
    assert status == 200 and ack["text"] == "quiet now" and ack["request_id"] != "mine"

    # A built-in switch is checked by its own request model the same way, before anything is sent.
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/switches/attack/mode", {"mode": "off"})
    assert status == 422 and not ack["ok"] and ack["field"] == "mode" and 'must be "on" or "bypass"' in ack["error"]
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/switches/attack/mode", {"mode": "bypass"})
    assert status == 200 and ack["mode"] == "bypass"

    # The console's guards hold for this route as for the others: JSON only, and never from another origin.
    path, body_bytes = "/api/vehicles/1/switches/note", b'{"text":"from elsewhere"}'
    for headers, want in [({"Content-Type": "text/plain"}, 415),
                          ({"Content-Type": "application/json", "Origin": "https://evil.example"}, 403),
                          ({"Content-Type": "application/json", "Sec-Fetch-Site": "cross-site"}, 403)]:  # fmt: skip
        status, _, answer_bytes = await asyncio.to_thread(raw, bench.base, "POST", path, body_bytes, headers)
        assert status == want, (headers, status, answer_bytes)
    await asyncio.sleep(0.3)
    assert bench.proxy.control.controls.vehicle(1, "note").text == "quiet now"  # type: ignore[union-attr]

    # Only declared vehicle switches, only known vehicles.
    for path, words in [("/api/vehicles/1/switches/routes", "no vehicle switch 'routes'"),
                        ("/api/vehicles/1/switches/nope", "no vehicle switch 'nope'"),
                        ("/api/vehicles/9/switches/note", "no vehicle 9")]:  # fmt: skip
        status, answer = await asyncio.to_thread(call, bench.base, path, {"text": "hi"})
        assert status == 404 and words in answer["error"], (path, answer)


async def test_the_watch_view_draws_a_column_for_the_new_switch(bench: Bench) -> None:
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/switches/note", {"text": "WALL"})
    assert status == 200 and ack["warnings"] == [SHOUTING]
    await until(lambda: (row(bench.fleet, 1)["switches"]["note"] or {}).get("text") == "WALL")
    board = Board()  # fed what the console received from the proxy, as secuav-attack's session feeds it
    for r in bench.fleet.summary():
        for kind, state in r["switches"].items():
            board.receive(f"secuav/v{r['sysid']}/{kind}/state", json.dumps(state).encode())
    assert board.refused == 0
    lines = table(board, Rates(), time.monotonic())
    head = lines[0].split()
    assert head[:6] == ["vehicle", "proxy", "attack", "mode", "secure", "note"]
    assert lines[1].split()[:5] == ["v1", "?", "none", "on", "n/a"]  # no proxy record, no secure stage here
    assert lines[1][lines[0].index("note") :].startswith("WALL (1 warning)  "), lines
    assert lines[2].split()[5] == "-"  # v2 has no note: its one field is null

    switches.unregister("note")  # without it, the table is the one the built-in switches give
    assert table(board, Rates(), time.monotonic())[0].split() == " ".join(COLUMNS).split()


async def test_the_page_lists_the_new_switch_in_the_vehicle_panel_and_sets_it(
    bench: Bench,
    browser: object,
) -> None:
    from selenium.webdriver.common.by import By

    driver = browser
    await asyncio.to_thread(driver.get, bench.base + "/")  # type: ignore[attr-defined]

    def panel() -> dict[str, Any]:  # read in one script: the panel is refreshed 12.5 times a second
        return driver.execute_script(  # type: ignore[attr-defined,no-any-return]
            "const li = document.querySelector('#switches li[data-kind=\"note\"]');"
            "return {shown: !document.getElementById('switches-panel').hidden,"
            " kinds: [...document.querySelectorAll('#switches > li')].map(l => l.dataset.kind),"
            " state: li ? li.querySelector('.switch-state').textContent : null,"
            " warnings: li ? [...li.querySelectorAll('.warnings li')].map(w => w.textContent) : []};"
        )

    async def shows(state: str) -> dict[str, Any]:
        deadline = time.monotonic() + 10
        while (now := await asyncio.to_thread(panel))["state"] != state:
            assert time.monotonic() < deadline, now
            await asyncio.sleep(0.1)
        return now

    first = await shows('{"text":null}')  # vehicle v1, selected as the first row
    assert first["shown"] and first["kinds"] == ["note"] and first["warnings"] == []  # the built-ins have controls

    def send(text: str) -> None:
        field = driver.find_element(By.CSS_SELECTOR, "#switches li[data-kind='note'] input.switch-request")  # type: ignore[attr-defined]
        field.clear()
        field.send_keys(text)
        driver.find_element(By.CSS_SELECTOR, "#switches li[data-kind='note'] button").click()  # type: ignore[attr-defined]

    await asyncio.to_thread(send, '{"text": "HELLO WALL"}')
    now = await shows('{"text":"HELLO WALL"}')
    assert now["warnings"] == [SHOUTING]
    ack = await asyncio.to_thread(lambda: driver.find_element(By.ID, "ack").text)  # type: ignore[attr-defined]
    assert ack.startswith("note: ok") and 'note: {"text":"HELLO WALL"}' in ack, ack
    assert bench.proxy.control is not None
    assert bench.proxy.control.controls.vehicle(1, "note").text == "HELLO WALL"  # type: ignore[union-attr]
    assert bench.proxy.control.controls.vehicle(2, "note").text is None  # type: ignore[union-attr]

    logged = await asyncio.to_thread(driver.get_log, "browser")  # type: ignore[attr-defined]
    errors = [e for e in logged if e["level"] in ("SEVERE", "WARNING")]
    assert errors == [], errors

"""The console's JSON API over real HTTP (uvicorn on loopback) and a real broker, with the proxy's own
control plane (``ControlPlane`` + ``vehicle_controls``) answering, as a script would use it."""

from __future__ import annotations

import asyncio
import base64
import json
import subprocess
import sys
import urllib.error
import urllib.request
from typing import Any

import pytest

from secuav_common.broker import BrokerAddress
from tests.support.console import Bench, call, serve
from webconsole.fleet import Session

pytestmark = pytest.mark.timeout(60)


async def test_vehicles_library_and_a_profile_round_trip(bench: Bench) -> None:
    status, rows = await asyncio.to_thread(call, bench.base, "/api/vehicles")
    assert status == 200 and rows[0]["sysid"] == 1 and rows[0]["instances"] == ["lab"] and rows[0]["online"]
    status, one = await asyncio.to_thread(call, bench.base, "/api/vehicles/1")
    assert status == 200 and one["world"]["walls"][0]["name"] == "wall" and one["world"]["vehicles"]["1"]["sensors"]
    status, lib = await asyncio.to_thread(call, bench.base, "/api/library")
    spoof = next(p for p in lib if p["name"] == "wall-spoof")
    assert spoof["parameters"]["rate_per_s"]["default"] == 0.2 and "rules:" in spoof["text"]

    body = {"profile": "wall-spoof", "params": {"rate_per_s": 0.5}}
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", body)
    assert status == 200 and ack["ok"] and ack["profile"] == "wall-spoof"
    assert bench.slots[1].engine is not None and bench.slots[1].state.hash == ack["hash"]

    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", {"profile": None})
    assert status == 200 and ack["ok"] and ack["profile"] is None and bench.slots[1].engine is None

    profile = {"name": "obj", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 2}, "kind": "bias",
                                         "offset_m": 0.5}]}  # fmt: skip
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", {"profile": profile})
    assert status == 200 and ack["profile"] == "obj"


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"profile": "wall-spooof"}, None, "no such library profile"),
        ({"profile": "wall-spoof", "params": {"rate": 1}}, None, "rate"),
        ({"profile": "name: x\nrules:\n  - target: {message: NOPE}\n    kind: bias\n    offset_m: 1\n"}, "rules[0]",
         "NOPE"),
        ({"profile": 7}, "profile", "library name"),
    ],
)
async def test_a_bad_profile_never_leaves_the_console(bench: Bench, body: Any, field: str | None, words: str) -> None:
    before = bench.slots[1].verdict  # replaced by every request the slot handles, even a refused one
    status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", body)
    assert status == 422 and not answer["ok"] and words in answer["error"], answer
    if field is not None:
        assert str(answer["field"]).startswith(field)
    await asyncio.sleep(0.3)
    assert bench.slots[1].verdict is before  # the proxy saw nothing, not even a rejection


async def test_mode_secure_unknown_vehicles_and_a_silent_proxy(bench: Bench) -> None:
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack/mode", {"mode": "bypass"})
    assert status == 200 and ack["mode"] == "bypass"
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack/mode", {"mode": "off"})
    assert status == 422 and ack["field"] == "mode"
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/secure", {"estimator": "secekf"})
    assert status == 409 and "not available" in ack["error"]  # refused by the proxy: it has no scenario
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/9/attack", {"profile": None})
    assert status == 404 and "no vehicle 9" in ack["error"]
    await bench.plane.aclose()  # the proxy goes cleanly (its record says offline): 404 at once (issue 36)
    for _ in range(100):
        if not bench.fleet.owners():
            break
        await asyncio.sleep(0.05)
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", {"profile": "wall-spoof"})
    assert status == 404 and "stopped" in ack["error"]
    # A proxy that says it is online but does not answer (stuck, or gone before its will fired): 504.
    bench.fleet.on_message("secuav/proxy/stuck/online", {"instance": "stuck", "online": True, "vehicles": [1]})
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack", {"profile": "wall-spoof"})
    assert status == 504 and "no acknowledgement" in ack["error"]


async def test_estimators_are_listed_with_their_declared_parameters(bench: Bench) -> None:
    status, names = await asyncio.to_thread(call, bench.base, "/api/estimators")
    assert status == 200 and names[0] == "off"
    status, described = await asyncio.to_thread(call, bench.base, "/api/estimators/params")
    assert status == 200 and [e["name"] for e in described] == names[1:]
    by_name = {e["name"]: e for e in described}
    secekf = by_name["secekf"]
    assert secekf["dist"] == "secuav" and secekf["object"] == "estimators.secekf:SecEkf"
    assert secekf["summary"].startswith("SecEKF")
    assert secekf["params"]["window"] == {"default": 10, "low": None, "high": None}
    assert secekf["params"]["alpha"] == {"default": 0.01, "low": 1e-6, "high": 0.5}
    assert secekf["params"]["s"]["default"] is None
    huber = by_name["huber"]  # examples/plugin, installed beside secuav by scripts/setup.sh
    assert huber["dist"] == "secuav-example-plugin" and huber["object"] == "secuav_example_plugin.huber:Huber"
    assert list(huber["params"])[:2] == ["huber_k", "n_irls"]  # its own first, then the shared ones
    assert huber["params"]["huber_k"] == {"default": 1.345, "low": 0.5, "high": 5.0}


async def test_secure_params_reach_the_proxy_which_checks_them(secure_bench: Bench) -> None:
    bench = secure_bench
    body = {"estimator": "huber", "params": {"huber_k": 2.0, "n_irls": 4}}
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/secure", body)
    assert status == 200 and ack["ok"] and ack["estimator"] == "huber", ack
    assert ack["params"] == {"huber_k": 2.0, "n_irls": 4}
    for _ in range(50):  # the retained state comes back over the broker into the fleet's row
        if bench.fleet.summary()[0]["secure_params"] == ack["params"]:
            break
        await asyncio.sleep(0.1)
    row = bench.fleet.summary()[0]
    assert row["secure"] == "huber" and row["secure_params"] == {"huber_k": 2.0, "n_irls": 4}

    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/secure",
                                          {"estimator": "huber", "params": {"huber_k": 9.0}})  # fmt: skip
    assert status == 409 and not ack["ok"] and "huber_k" in ack["error"] and "[0.5, 5.0]" in ack["error"], ack
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/secure",
                                          {"estimator": "secekf", "params": {"huber_k": 2.0}})  # fmt: skip
    assert status == 409 and "huber_k" in ack["error"] and "secekf" in ack["error"], ack
    assert ack["estimator"] == "huber" and ack["params"] == {"huber_k": 2.0, "n_irls": 4}  # the running one stays


async def test_the_stream_sends_the_fleet_and_the_watched_vehicles_samples(bench: Bench) -> None:
    bench.plane.publish_nowait("secuav/v1/truth", {"pos_ned_m": [0.5, 0.0, -2.5]})
    bench.plane.publish_nowait("secuav/v1/readings", {"sysid": 1, "sensors": {"0": {"original_m": 2.5,
                               "forwarded_m": 3.5, "flagged": False}}})  # fmt: skip

    def read_events() -> list[dict[str, Any]]:
        events = []
        with urllib.request.urlopen(bench.base + "/api/stream?vehicle=1", timeout=10) as response:
            for raw in response:
                line = raw.decode().strip()
                if line.startswith("data:"):
                    events.append(json.loads(line[5:]))
                    if sum(len(e["samples"]) for e in events) >= 2 or len(events) >= 30:
                        break
        return events

    events = await asyncio.to_thread(read_events)
    samples = [s for e in events for s in e["samples"]]
    assert events[0]["fleet"][0]["sysid"] == 1
    readings = next(s for s in samples if s["kind"] == "readings")
    assert readings["sensors"]["0"]["original_m"] == 2.5 and readings["sensors"]["0"]["forwarded_m"] == 3.5
    assert readings["sensors"]["0"]["truth_m"] == pytest.approx(4.5)  # 5 m wall, 0.5 m north of home
    assert any(s["kind"] == "truth" for s in samples)


async def test_a_password_guards_page_and_api(bench: Bench) -> None:
    session = Session(BrokerAddress("127.0.0.1", 1), bench.fleet, "http://test/")
    async with serve(bench.fleet, session, password="s3cret") as base:
        status, _ = await asyncio.to_thread(call, base, "/api/vehicles")
        assert status == 401
        basic = "Basic " + base64.b64encode(b"anyone:s3cret").decode()
        assert (await asyncio.to_thread(call, base, "/api/vehicles", None, basic))[0] == 200
        assert (await asyncio.to_thread(call, base, "/api/vehicles", None, "Bearer s3cret"))[0] == 200
        assert (await asyncio.to_thread(call, base, "/api/vehicles", None, "Bearer nope"))[0] == 401


def test_serving_beyond_loopback_needs_a_password() -> None:
    run = subprocess.run([sys.executable, "-m", "webconsole", "--listen", "0.0.0.0:18080", "--broker", "mqtt://127.0.0.1:1"],
                         capture_output=True, text=True, timeout=30)  # fmt: skip
    assert run.returncode == 2 and "needs a password" in run.stderr

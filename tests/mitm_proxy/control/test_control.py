"""The MQTT control plane against real brokers: the embedded amqtt and mosquitto, on loopback."""

from __future__ import annotations

import asyncio
import json
import logging
import os
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from attack_profiles import library
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import MAX_PAYLOAD_BYTES, ONLINE_TOPIC, ControlPlane
from mitm_proxy.control.switch import Switch
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.payloads import SecureState
from secuav_common.controlplane.switches.secure import CONTRACT as secure_contract
from tests.support.brokers import MOSQUITTO, Mosquitto, Observer

pytestmark = pytest.mark.timeout(60)

BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.mosquitto)]
SET1, STATE1 = "secuav/v1/attack/set", "secuav/v1/attack/state"


@pytest.fixture(params=BROKERS)
async def broker_port(
    request: pytest.FixtureRequest, tcp_port: Callable[[], int], tmp_path: Path
) -> AsyncIterator[int]:
    port = tcp_port()
    if request.param == "amqtt":
        async with EmbeddedBroker(port=port) as broker:
            assert broker.started
            yield port
    else:
        if MOSQUITTO is None:
            if os.environ.get("CI"):  # .ci/run installs it: missing there is a setup bug, not a reason to skip
                pytest.fail("the mosquitto binary is not installed, but CI must test against it")
            pytest.skip("the mosquitto binary is not installed")
        with Mosquitto(port, tmp_path):
            yield port


def fake_stats() -> dict[int, dict[str, Any]]:
    return {1: {"downlink": {"frames_in": 5}}, 2: {"downlink": {"frames_in": 7}}}


@pytest.fixture
def slots() -> dict[int, AttackSlot]:
    return {1: AttackSwitch(AttackSlot(1)), 2: AttackSwitch(AttackSlot(2))}


async def test_library_profile_is_applied_acknowledged_and_retained(
    broker_port: int, slots: dict[int, AttackSlot]
) -> None:
    plane = ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats)
    async with plane, Observer(broker_port, ["secuav/#"]) as obs:
        await plane.wait_connected(10)
        initial = await obs.wait_for(STATE1)
        assert initial["ok"] and initial["profile"] is None and initial["sysid"] == 1
        assert await obs.wait_for(ONLINE_TOPIC) is True

        state = await obs.request(SET1, {"library": "wall-spoof", "parameters": {"start_s": 0}})
        expected = library.load("wall-spoof", start_s=0)
        assert state["ok"] and state["error"] is None
        assert state["profile"] == "wall-spoof" and state["hash"] == expected.content_hash()
        assert slots[1].engine is not None and slots[1].engine.profile == expected
        assert slots[2].engine is None  # only the addressed vehicle

        # A client that subscribes later reads the same state, retained.
        async with Observer(broker_port, [STATE1]) as late:
            body = await late.wait_for(STATE1)
            assert body["request_id"] == state["request_id"]
            assert late.messages[0][2] is True  # delivered as a retained message


async def test_rejected_profile_keeps_the_old_engine(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    async with ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/v1/#"]) as obs:
            good = await obs.request(SET1, {"library": "distance-stuck"})
            assert good["ok"]
            engine = slots[1].engine
            bad_profile = {"name": "bad", "rules": [{"target": {"message": "DISTANCE_SENSOR"}, "kind": "warp"}]}
            bad = await obs.request(SET1, bad_profile)
            assert not bad["ok"]
            assert "rules[0].kind" in bad["error"] and "warp" in bad["error"]
            assert bad["profile"] == "distance-stuck" and bad["hash"] == good["hash"]  # still the old one
            assert slots[1].engine is engine

            unknown = await obs.request(SET1, {"library": "no-such-profile"})
            assert not unknown["ok"] and "no-such-profile" in unknown["error"]
            assert slots[1].engine is engine


async def test_null_and_an_empty_request_clear(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    async with ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/v1/#"]) as obs:
            assert (await obs.request(SET1, {"library": "drift"}))["ok"]
            assert slots[1].engine is not None
            start = len(obs.messages)
            await obs.publish(SET1, None)  # the JSON literal null
            state = await obs.wait_for(STATE1, lambda b: b["profile"] is None, start=start)
            assert state["ok"] and state["hash"] is None and slots[1].engine is None

            assert (await obs.request(SET1, {"library": "drift"}))["ok"]
            cleared = await obs.request(SET1, None)  # {"request_id": ...} alone clears too
            assert cleared["ok"] and cleared["profile"] is None and slots[1].engine is None


async def test_oversized_binary_and_broken_payloads_are_refused(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    async with ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/v1/#"]) as obs:
            assert (await obs.request(SET1, {"library": "drift"}))["ok"]
            engine = slots[1].engine

            # Oversized: refused before decoding, yet answered (the request id leads the JSON).
            big = {"request_id": "big-1", "name": "x", "description": "y" * MAX_PAYLOAD_BYTES, "rules": []}
            start = len(obs.messages)
            await obs.publish(SET1, json.dumps(big).encode())
            state = await obs.wait_for(STATE1, lambda b: b["request_id"] == "big-1", start=start)
            assert not state["ok"] and "larger than 65536 bytes" in state["error"]

            cases = {
                b"\xff\xfe\x00binary": "not UTF-8",
                b'{"request_id": "nj-1", "library": ': "not JSON",
                b"   ": "empty payload",
            }
            for raw, reason in cases.items():
                start = len(obs.messages)
                await obs.publish(SET1, raw)
                state = await obs.wait_for(STATE1, lambda b, why=reason: why in (b["error"] or ""), start=start)
                assert not state["ok"]
            assert state["profile"] == "drift" and slots[1].engine is engine
            assert (await obs.wait_for(STATE1, lambda b: b["request_id"] == "nj-1"))["ok"] is False


async def test_unknown_vehicle_is_logged_once(
    broker_port: int, slots: dict[int, AttackSlot], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="mitm_proxy.control")
    async with ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/#"]) as obs:
            for _ in range(3):
                await obs.publish("secuav/v9/attack/set", {"library": "drift"})
                await obs.publish("secuav/drone/attack/set", {"library": "drift"})
            # A request to a known vehicle after them proves the unknown ones were handled (in order).
            assert (await obs.request(SET1, {"library": "drift"}))["ok"]
            assert obs.on("secuav/v9/attack/state") == []
    unknown = [r for r in caplog.records if r.getMessage() == "control.unknown_vehicle"]
    assert len(unknown) == 2


async def test_stats_are_published_about_once_a_second(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    plane = ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats)
    async with plane, Observer(broker_port, ["secuav/+/stats"]) as obs:
        await plane.wait_connected(10)
        await asyncio.sleep(3.3)
    v1 = obs.on("secuav/v1/stats")
    assert v1[0] == {"downlink": {"frames_in": 5}}
    assert obs.on("secuav/v2/stats")[0] == {"downlink": {"frames_in": 7}}
    assert 2 <= len(v1) <= 4  # 1 Hz over ~3.3 s, whatever the connect took


async def test_secure_set_without_and_with_a_secure_stage(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    url = f"mqtt://127.0.0.1:{broker_port}"
    async with ControlPlane(url, vehicle_controls("t", slots), stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/v1/secure/#"]) as obs:
            initial = await obs.wait_for("secuav/v1/secure/state")
            assert initial["available"] is False and initial["request_id"] is None
            state = await obs.request("secuav/v1/secure/set", {"estimator": "secekf"})
            assert not state["ok"] and "not available" in state["error"]
            start = len(obs.messages)
            await obs.publish("secuav/v1/secure/set", "recap")  # no request_id: still a request, still refused
            anonymous = await obs.wait_for("secuav/v1/secure/state", start=start)
            assert not anonymous["ok"] and anonymous["request_id"] is None

    class BrokenSlot(Switch[SecureState]):  # a secure stage whose code raises: the plane reports it, serves on
        contract = secure_contract

        def apply(self, payload: Any, source: str) -> None:
            raise RuntimeError("boom")

        def current(self) -> dict[str, Any]:
            return {"sysid": 2, "estimator": None}

    controls = vehicle_controls("t", slots, secure={2: BrokenSlot()})
    async with ControlPlane(url, controls, stats=fake_stats) as plane:
        await plane.wait_connected(10)
        async with Observer(broker_port, ["secuav/v2/secure/#", STATE1]) as obs:
            failed = await obs.request("secuav/v2/secure/set", {"estimator": "rarse"})
            assert not failed["ok"] and "boom" in failed["error"]
            assert (await obs.request(SET1, {"library": "wall-spoof"}))["ok"]  # the plane still serves


INSTANCE_ONLINE = "secuav/proxy/t/online"


async def test_clean_stop_says_offline(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    async with Observer(broker_port, [ONLINE_TOPIC, INSTANCE_ONLINE]) as obs:
        async with ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots), stats=fake_stats,
                                describe=lambda: {"pid": 42}) as plane:  # fmt: skip
            await plane.wait_connected(10)
            await obs.wait_for(ONLINE_TOPIC, lambda b: b is True)
            record = await obs.wait_for(INSTANCE_ONLINE, lambda b: b["online"])
            assert record["instance"] == "t" and record["vehicles"] == [1, 2] and record["pid"] == 42
        await obs.wait_for(ONLINE_TOPIC, lambda b: b is False)
        gone = await obs.wait_for(INSTANCE_ONLINE, lambda b: not b["online"])
        assert gone["instance"] == "t" and gone["since"] == record["since"]


async def test_last_will_fires_when_the_connection_dies(broker_port: int, slots: dict[int, AttackSlot]) -> None:
    async with Observer(broker_port, [INSTANCE_ONLINE]) as obs:
        controls = vehicle_controls("t", slots)
        plane = ControlPlane(f"mqtt://127.0.0.1:{broker_port}", controls, stats=fake_stats, backoff_s=(30.0, 30.0))
        async with plane:
            await plane.wait_connected(10)
            await obs.wait_for(INSTANCE_ONLINE, lambda b: b["online"] is True)
            start = len(obs.messages)
            # Cut the TCP connection under the client, as a crash or a pulled cable would:
            # the broker, not the plane, must announce that the proxy is gone.
            assert plane._client is not None
            sock = plane._client._client.socket()
            sock.shutdown(2)
            will = await obs.wait_for(INSTANCE_ONLINE, lambda b: b["online"] is False, start=start)
            assert will["instance"] == "t" and will["vehicles"] == [1, 2]
            assert not plane.connected.is_set() or await _cleared(plane)


async def _cleared(plane: ControlPlane) -> bool:
    for _ in range(50):
        if not plane.connected.is_set():
            return True
        await asyncio.sleep(0.1)
    return False


async def test_no_broker_means_no_mqtt_and_publish_is_a_no_op(slots: dict[int, AttackSlot]) -> None:
    async with ControlPlane(None, vehicle_controls("t", slots), stats=fake_stats) as plane:
        plane.publish_nowait("secuav/v1/estimate", {"x": 1})
        assert not plane.connected.is_set() and plane.dropped == 0
        assert len(plane.outbox.queue) == 0


async def test_the_real_secure_slot_through_the_plane(broker_port: int) -> None:
    from mitm_proxy.control.secure import SecureSwitch
    from mitm_proxy.stages.secure.stage import OFF, SecureStage
    from secuav_common.scenario import load_scenario

    scenario = load_scenario("scenarios/wall_hover.yaml")
    secure_slots = {1: SecureSwitch(SecureStage(OFF, scenario, 1))}
    controls = vehicle_controls("t", {1: AttackSwitch(AttackSlot(1, scenario))}, secure=secure_slots)
    plane = ControlPlane(f"mqtt://127.0.0.1:{broker_port}", controls, stats=fake_stats)
    topic = "secuav/v1/secure/state"
    async with plane, Observer(broker_port, ["secuav/v1/secure/#"]) as obs:
        await plane.wait_connected(10)
        assert (await obs.wait_for(topic))["estimator"] is None
        state = await obs.request("secuav/v1/secure/set", {"estimator": "recap"})
        assert state["ok"] and state["estimator"] == "recap" and state["group"] == "wall"
        bad = await obs.request("secuav/v1/secure/set", {"estimator": "nope"})
        assert not bad["ok"] and "unknown estimator" in bad["error"] and bad["estimator"] == "recap"
        # A change made outside MQTT (the app, a config reload) is published too.
        secure_slots[1].offer_payload("secekf", "local-1")
        local = await obs.wait_for(topic, lambda b: b["request_id"] == "local-1")
        assert local["estimator"] == "secekf"


async def test_attack_mode_switches_bypass_at_runtime_and_keeps_the_profile(
    broker_port: int, slots: dict[int, AttackSlot]
) -> None:
    from mitm_proxy.stages.attack import AttackStage

    stages = {sysid: AttackStage(slot.slot) for sysid, slot in slots.items()}
    plane = ControlPlane(f"mqtt://127.0.0.1:{broker_port}", vehicle_controls("t", slots, stages), stats=fake_stats)
    mode_set, mode_state = "secuav/v1/attack/mode/set", "secuav/v1/attack/mode/state"
    async with plane, Observer(broker_port, ["secuav/v1/attack/#"]) as obs:
        await plane.wait_connected(10)
        assert (await obs.wait_for(mode_state))["mode"] == "on"
        assert (await obs.request(SET1, {"library": "distance-stuck"}))["ok"]
        assert stages[1].active

        state = await obs.request(mode_set, {"mode": "bypass"})
        assert state["ok"] and state["mode"] == "bypass" and state["error"] is None
        assert not stages[1].active and stages[2].enabled  # only vehicle 1
        assert slots[1].engine is not None  # bypass keeps the profile for later

        bad = await obs.request(mode_set, {"mode": "off"})
        assert not bad["ok"] and 'must be "on" or "bypass"' in bad["error"] and bad["mode"] == "bypass"
        assert bad["since"] == state["since"]

        start = len(obs.messages)
        await obs.publish(mode_set, "on")  # the bare JSON string works too
        assert (await obs.wait_for(mode_state, lambda b: b["mode"] == "on", start=start))["ok"]
        assert stages[1].active

        stages[1].enabled = False  # switched by someone else (the app): published all the same
        changed = await obs.wait_for(mode_state, lambda b: b["mode"] == "bypass", start=start)
        assert changed["request_id"] is None

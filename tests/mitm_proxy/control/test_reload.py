"""The ``--profile`` file reload: a good edit swaps, a bad edit keeps the old profile and says why."""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from attack_profiles.profile import load_profile
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import ControlPlane
from mitm_proxy.control.reload import REHASH_EVERY, ProfileWatcher
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.payloads import AttackState as SlotState
from secuav_common.scenario import load_scenario
from tests.support.brokers import Observer


def profile_text(name: str, offset_m: float = 1.0, sysid: int | None = None, sensor_id: int = 0) -> str:
    vehicle = f", sysid: {sysid}" if sysid is not None else ""
    return (
        f"name: {name}\n"
        "rules:\n"
        f"  - target: {{message: DISTANCE_SENSOR{vehicle}, sensor_id: {sensor_id}, field: current_distance}}\n"
        "    kind: bias\n"
        f"    offset_m: {offset_m}\n"
    )


def write(path: Path, text: str) -> None:
    """Write and make sure the mtime moves even on a coarse-clock file system."""
    before = path.stat().st_mtime_ns if path.exists() else 0
    path.write_text(text, encoding="utf-8")
    if path.stat().st_mtime_ns == before:
        os.utime(path, ns=(before + 1_000_000, before + 1_000_000))


def started(path: Path, slots: dict[int, AttackSlot]) -> ProfileWatcher:
    """As the proxy starts: the file's profile offered to every slot, then the watcher made."""
    profile = load_profile(path)
    for slot in slots.values():
        assert slot.offer(profile, "--profile").ok
    return ProfileWatcher(path, slots)


def names(slots: dict[int, AttackSlot]) -> dict[int, str | None]:
    return {sysid: slot.state.profile for sysid, slot in slots.items()}


def test_a_good_edit_swaps_and_an_unchanged_save_does_nothing(tmp_path: Path) -> None:
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first"))
    slots = {1: AttackSwitch(AttackSlot(1)), 2: AttackSwitch(AttackSlot(2))}
    watcher = started(path, slots)
    assert watcher.poll() == []

    write(path, profile_text("second", offset_m=2.5))
    states = watcher.poll()
    assert [s.ok for s in states] == [True, True]
    assert names(slots) == {1: "second", 2: "second"}
    assert slots[1].engine is not None and slots[1].engine.profile.rules[0].offset == 2.5
    assert slots[1].state.request_id == f"file:{path}"

    engine = slots[1].engine
    write(path, profile_text("second", offset_m=2.5))  # saved again, same content
    os.utime(path)
    assert watcher.poll() == [] and slots[1].engine is engine
    assert watcher.reloads == 1


def test_a_bad_edit_keeps_the_old_profile_and_names_file_and_field(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="mitm_proxy.control.reload")
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first"))
    slots = {1: AttackSwitch(AttackSlot(1))}
    watcher = started(path, slots)
    engine = slots[1].engine

    write(path, profile_text("broken").replace("kind: bias", "kind: warp"))
    [state] = watcher.poll()
    assert not state.ok and state.profile == "first" and slots[1].engine is engine
    assert state.error is not None and str(path) in state.error and "rules[0].kind" in state.error
    assert "warp" in state.error

    write(path, "name: [unclosed\n")
    [state] = watcher.poll()
    assert not state.ok and str(path) in (state.error or "") and slots[1].engine is engine
    assert watcher.poll() == []  # the same bad file is reported once, not at every poll
    assert [r.getMessage() for r in caplog.records].count("reload.rejected") == 2

    write(path, profile_text("fixed"))
    [state] = watcher.poll()
    assert state.ok and state.profile == "fixed" and state.error is None


def test_an_editor_that_writes_a_temp_file_and_renames_it(tmp_path: Path) -> None:
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first"))
    slots = {1: AttackSwitch(AttackSlot(1))}
    watcher = started(path, slots)
    tmp = tmp_path / ".attack.yaml.swp"
    tmp.write_text(profile_text("renamed"), encoding="utf-8")
    os.replace(tmp, path)
    assert [s.profile for s in watcher.poll()] == ["renamed"]


def test_rules_that_name_vehicles_go_to_those_vehicles_only(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="mitm_proxy.control.reload")
    path = tmp_path / "attack.yaml"
    write(path, profile_text("for-2", sysid=2))
    slots = {1: AttackSwitch(AttackSlot(1)), 2: AttackSwitch(AttackSlot(2)), 3: AttackSwitch(AttackSlot(3))}
    watcher = ProfileWatcher(path, slots)
    watcher.apply_now()
    assert names(slots) == {1: None, 2: "for-2", 3: None}

    write(path, profile_text("for-1", sysid=1))
    watcher.poll()
    assert names(slots) == {1: "for-1", 2: None, 3: None}  # 2 no longer named: the file's profile leaves it

    # Vehicle 1 is given another profile by hand (MQTT); an edit that drops 1 must not clear that.
    slots[1].offer_payload({"library": "drift"}, "mqtt-1")
    write(path, profile_text("for-3", sysid=3))
    watcher.poll()
    assert names(slots) == {1: "drift", 2: None, 3: "for-3"}

    write(path, profile_text("for-9", sysid=9))
    watcher.poll()
    assert any(r.getMessage() == "reload.no_such_vehicle" for r in caplog.records)
    assert names(slots) == {1: "drift", 2: None, 3: None}


def test_a_profile_the_scenario_refuses_keeps_the_old_one(tmp_path: Path) -> None:
    slots = {1: AttackSwitch(AttackSlot(1, load_scenario("scenarios/wall_hover.yaml")))}
    path = tmp_path / "attack.yaml"
    write(path, profile_text("ok", sensor_id=0))
    watcher = ProfileWatcher(path, slots)
    assert [s.ok for s in watcher.apply_now()] == [True]
    write(path, profile_text("no-such-sensor", sensor_id=7))
    [state] = watcher.poll()
    assert not state.ok and "sensor_id" in (state.error or "") and state.profile == "ok"
    assert watcher.rejects == 1


def test_a_missing_file_keeps_the_profile_until_it_returns(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="mitm_proxy.control.reload")
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first"))
    slots = {1: AttackSwitch(AttackSlot(1))}
    watcher = started(path, slots)
    path.unlink()
    assert watcher.poll() == [] and watcher.poll() == []
    assert [r.getMessage() for r in caplog.records].count("reload.missing") == 1
    assert slots[1].state.profile == "first"
    write(path, profile_text("back"))
    assert [s.profile for s in watcher.poll()] == ["back"]


@pytest.mark.timeout(30)
async def test_the_running_watcher_reloads_and_the_plane_acknowledges_on_mqtt(
    tmp_path: Path, tcp_port: Callable[[], int]
) -> None:
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first"))
    slots = {1: AttackSwitch(AttackSlot(1))}
    seen: list[SlotState] = []
    watcher = started(path, slots)
    watcher.interval_s = 0.1
    watcher.on_state = seen.append
    port = tcp_port()

    def stats() -> dict[int, dict[str, Any]]:
        return {}

    async with (
        EmbeddedBroker(port=port),
        ControlPlane(f"mqtt://127.0.0.1:{port}", vehicle_controls("t", slots), stats=stats) as plane,
    ):
        await plane.wait_connected(10)
        async with Observer(port, ["secuav/v1/attack/state"]) as obs, watcher:
            task = asyncio.create_task(watcher.run())
            try:
                assert (await obs.wait_for("secuav/v1/attack/state"))["profile"] == "first"
                write(path, profile_text("second"))
                state = await obs.wait_for("secuav/v1/attack/state", lambda b: b["profile"] == "second")
                assert state["ok"] and state["request_id"] == f"file:{path}"
                write(path, "rules: 3\n")
                bad = await obs.wait_for("secuav/v1/attack/state", lambda b: not b["ok"])
                assert bad["profile"] == "second" and str(path) in bad["error"]
            finally:
                task.cancel()
                with pytest.raises(asyncio.CancelledError):
                    await task
    assert [s.profile for s in seen] == ["second", "second"] and [s.ok for s in seen] == [True, False]


def test_a_same_size_edit_within_one_timestamp_tick_is_still_seen(tmp_path: Path) -> None:
    path = tmp_path / "attack.yaml"
    write(path, profile_text("first", offset_m=1.0))
    slots = {1: AttackSwitch(AttackSlot(1))}
    watcher = started(path, slots)
    before = path.stat()
    path.write_text(profile_text("first", offset_m=2.0), encoding="utf-8")  # same size
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))  # as a coarse-clock file system would leave it
    assert path.stat().st_size == before.st_size
    states = [watcher.poll() for _ in range(REHASH_EVERY)]
    assert [len(s) for s in states] == [0] * (REHASH_EVERY - 1) + [1]
    assert slots[1].engine is not None and slots[1].engine.profile.rules[0].offset == 2.0

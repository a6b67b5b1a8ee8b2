"""Frame operations in the proxy: the attack stage, the pipeline's tick, the link's timer, signing.

Frames are real MAVLink (pymavlink packs them, pymavlink and our Signer check what comes out); the
link test runs the real proxy on loopback UDP.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import library
from attack_profiles.profile import parse_profile
from mavframe.frames import split
from mavframe.packet import Direction
from mavframe.signing import Signer
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from mitm_proxy.tools.attack_cli import _stats_line
from tests.support.frames_support import TEST_KEY, distance, heartbeat, mav, pack, parse_all, signed_mav

UP, DOWN = Direction.UPLINK, Direction.DOWNLINK
pytestmark = pytest.mark.timeout(60)


def linked(signer: Signer | None = None) -> tuple[AttackSlot, Pipeline, LinkStats]:
    slot = AttackSwitch(AttackSlot(1))
    stats = LinkStats(1)
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=stats, signer=signer)
    slot.slot.unkeyed = pipe.unkeyed_signed
    return slot, pipe, stats


def prof(*rules: dict[str, Any]) -> Any:
    return parse_profile({"name": "p", "rules": list(rules)}, "p.yaml")


def test_a_profile_that_would_forge_on_a_signed_direction_without_the_key_is_refused() -> None:
    slot, pipe, stats = linked()
    bias = prof({"target": {"message": "DISTANCE_SENSOR"}, "kind": "bias", "offset_m": 1.0})
    assert slot.offer(bias).ok
    pipe.feed(pack(heartbeat(), signed_mav(sysid=255)), UP, time.monotonic())  # the ground station signs
    assert stats[UP].signed == 1 and pipe.unkeyed_signed() == {UP}
    state = slot.offer(library.load("inject-rtl"))
    assert not state.ok and state.error is not None and "\n" not in state.error
    assert "rules[0]" in state.error and "the uplink of vehicle 1 is signed" in state.error
    assert "--signing-key" in state.error and slot.engine is not None and slot.engine.profile == bias  # it stays
    uplink_bias = prof({"target": {"message": "DISTANCE_SENSOR", "direction": "uplink"}, "kind": "bias",
                        "offset_m": 1.0})  # fmt: skip
    assert not slot.offer(uplink_bias).ok  # a rewrite needs the key too
    up_drop = prof({"target": {"message": "DISTANCE_SENSOR", "direction": "uplink"}, "kind": "drop"})
    assert slot.offer(up_drop).ok  # holding frames back needs no key
    assert slot.offer(prof({"kind": "duplicate", "target": {"message": "HEARTBEAT"}})).ok  # the downlink: unsigned
    assert slot.offer(None).ok


def test_with_the_key_forged_frames_are_signed_and_the_ground_stream_stays_valid() -> None:
    slot, pipe, stats = linked(Signer(TEST_KEY, link_id=7))
    gcs = signed_mav(sysid=255)
    gcs.srcComponent = 190
    now = time.monotonic()
    assert slot.offer(library.load("inject-rtl", start_s=0.0)).ok
    t = pipe.next_tick_s()
    assert t is not None and t > now + 1.0  # waits (at most 1.5 s) to hear the ground station it will be
    out = [o.data for o in pipe.feed(pack(heartbeat(), gcs), UP, now)]
    t = pipe.next_tick_s()
    assert t is not None and t <= now + 0.1  # heard: due at once
    out += [o.data for _d, o in pipe.tick(t)]
    out += [o.data for o in pipe.feed(pack(heartbeat(), gcs), UP, now)]
    frames = [raw for data in out for _h, raw in split(data).frames]
    check = Signer(TEST_KEY)  # the vehicle's view: every frame authentic and fresh
    assert [check.verify(f) for f in frames] == [None, None, None]
    msgs = parse_all(b"".join(frames))
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "COMMAND_LONG", "HEARTBEAT"]
    assert [m.get_seq() for m in msgs] == [0, 1, 2] and frames[1][-13] == 7  # the proxy's own link id
    assert msgs[1].command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
    assert (msgs[1].get_srcSystem(), msgs[1].get_srcComponent()) == (255, 190)
    assert stats[UP].injected == 1 and stats[UP].resigned == 2  # the forged frame, and the renumbered heartbeat


def test_signing_that_starts_after_the_profile_withholds_the_forged_frames_and_says_so() -> None:
    slot, pipe, stats = linked()
    assert slot.offer(library.load("inject-rtl", start_s=0.0)).ok
    pipe.feed(pack(heartbeat(), signed_mav(sysid=255)), UP, time.monotonic())  # the stage cannot read it
    assert pipe.tick(time.monotonic() + 2.0) == []  # not heard: due after 1.5 s, then withheld
    assert stats[UP].injected == 0 and stats[UP].signed_untouched == 2  # the heartbeat, the forged command
    assert any(w.startswith("attack.signed_no_key") for w in slot.slot.warnings)


def test_duplicates_are_counted_and_status_says_so() -> None:
    slot, pipe, stats = linked()
    assert slot.offer(prof({"kind": "duplicate", "target": {"message": "DISTANCE_SENSOR"}, "copies": 2})).ok
    pipe.next_tick_s()
    veh = mav(1, 1)
    out = [o.data for k in range(3) for o in pipe.feed(pack(distance(sensor_id=k), veh), DOWN, time.monotonic())]
    msgs = parse_all(b"".join(out))
    assert [m.id for m in msgs] == [0, 0, 0, 1, 1, 1, 2, 2, 2] and [m.get_seq() for m in msgs] == list(range(9))
    snap = stats.snapshot()
    assert snap["downlink"]["injected"] == snap["downlink"]["duplicated"] == 6 and snap["downlink"]["replayed"] == 0
    assert "injected 6 (duplicated 6, replayed 0)" in _stats_line(snap)


async def test_the_link_sends_spoofed_heartbeats_on_its_timer_and_keeps_none_when_idle(
    udp_port: Callable[[], int],
) -> None:
    from tests.support.udp_peers import Peer

    vehicle, gcs = Peer(), Peer()
    veh = udp_port()
    cfg = ProxyConfig(links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                                        ground=[f"udpout://127.0.0.1:{gcs.port}"])], broker="none")  # fmt: skip
    try:
        async with Proxy(cfg) as proxy:
            link = proxy.links[0]
            assert link._tick is None  # no profile: no timer
            m = mav(1, 1)
            vehicle.send(pack(heartbeat(), m), veh)
            await gcs.frames(0.2)
            spoof = prof({"kind": "inject", "target": {"message": "HEARTBEAT", "direction": "downlink"},
                          "rate_hz": 20, "count": 5, "fields": {"type": "MAV_TYPE_FIXED_WING"}})  # fmt: skip
            assert proxy.slots[1].offer(spoof).ok
            assert link._tick is not None  # armed by the install, without any frame arriving
            for _ in range(4):
                vehicle.send(pack(heartbeat(), m), veh)
                await asyncio.sleep(0.05)
            got, _ = await gcs.frames(0.4)
            assert link._tick is None  # all five sent: nothing scheduled, no timer
    finally:
        vehicle.close()
        gcs.close()
    msgs = parse_all(b"".join(got))
    assert sum(x.type == mavlink.MAV_TYPE_FIXED_WING for x in msgs) == 5
    assert sum(x.type != mavlink.MAV_TYPE_FIXED_WING for x in msgs) == 4
    seqs = [x.get_seq() for x in msgs]
    assert seqs[0] == 1 and all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(seqs)), seqs


def test_the_stage_tells_its_clock_when_the_profile_or_the_bypass_changes() -> None:
    slot = AttackSwitch(AttackSlot(1))
    stage = AttackStage(slot.slot)
    calls: list[int] = []
    stage.on_schedule = lambda: calls.append(1)
    assert slot.offer(library.load("inject-rtl")).ok  # installed
    stage.enabled = False  # what secuav/v1/attack/mode/set bypass writes
    stage.enabled = False  # no change: nothing to say
    stage.active = True
    assert slot.offer(None).ok  # cleared
    assert len(calls) == 4 and stage.next_due_s() is None


async def test_a_recorded_stream_is_replayed_by_the_link_with_contiguous_numbers(udp_port: Callable[[], int]) -> None:
    from tests.support.udp_peers import Peer

    vehicle, gcs = Peer(), Peer()
    veh = udp_port()
    cfg = ProxyConfig(links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                                        ground=[f"udpout://127.0.0.1:{gcs.port}"])], broker="none")  # fmt: skip
    replay = prof({"kind": "frame_replay", "target": {"message": "STATUSTEXT", "direction": "downlink"},
                   "record_start_s": 0, "record_end_s": 1.0, "start_s": 1.0})  # fmt: skip
    m = mav(1, 1)
    try:
        async with Proxy(cfg) as proxy:
            assert proxy.slots[1].offer(replay).ok
            assert proxy.links[0]._tick is None  # nothing recorded, nothing to play: no timer
            for k in range(5):
                vehicle.send(pack(mavlink.MAVLink_statustext_message(6, f"line {k}".encode()), m), veh)
            got, _ = await gcs.frames(3.0)  # the five as they came, then (from 1 s) the five again
            snap = proxy.stats_snapshot()[1]["downlink"]
    finally:
        vehicle.close()
        gcs.close()
    msgs = parse_all(b"".join(got))
    assert [x.text for x in msgs] == [f"line {k}" for k in range(5)] * 2
    assert [x.get_seq() for x in msgs] == list(range(10))  # the replayed frames follow on, no repeat
    assert snap["replayed"] == snap["injected"] == 5

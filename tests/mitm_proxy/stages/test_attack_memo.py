"""The attack stage's side of a repeated rewrite: memo_fields, memo_token and pkt.steady_until_s.

The pipeline lets the fast route repeat what the stage did to a frame until ``pkt.steady_until_s``, for the
messages in ``memo_fields``, while ``memo_token`` stays the same (mitm_proxy/README.md, "The fast path").
"""

from __future__ import annotations

import math
import time
from typing import Any

import pytest

from attack_profiles.profile import Profile, parse_profile
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import distance, global_position, heartbeat, pack

DOWN = Direction.DOWNLINK
DS, GLOBAL_POSITION_INT = 132, 33


def prof(*rules: dict[str, Any]) -> Profile:
    return parse_profile({"name": "memo", "rules": list(rules)}, "memo.yaml")


def ds(kind: str, sensor_id: Any = 0, **kw: Any) -> dict[str, Any]:
    return {"target": {"message": "DISTANCE_SENSOR", "sensor_id": sensor_id}, "kind": kind, **kw}


def packet(frame: bytes) -> Packet:
    ((h, raw),) = split(frame).frames
    return Packet(raw, h, DOWN, 0, time.monotonic())


def staged(profile: Profile | None) -> AttackStage:
    slot = AttackSlot(1)
    slot.apply(profile, "memo.yaml")
    return AttackStage(slot)


def test_a_biased_frame_says_until_when_its_rewrite_holds() -> None:
    stage = staged(prof(ds("bias", 1, offset_m=0.5), ds("bias", 2, offset_m=0.5, start_s=5.0, end_s=6.0)))
    assert stage.memo_fields == {DS: "time_boot_ms"}
    engine = stage.slot.engine
    assert engine is not None
    start = time.monotonic()
    engine.activate(start)  # restart the profile clock at a known instant
    p = packet(pack(distance(cm=200, sensor_id=1)))
    (out,) = stage.process(p, start + 1.0)
    assert out.changed and out.fields is not None and out.fields["current_distance"] == 250
    assert out.steady_until_s == math.inf  # always on
    p = packet(pack(distance(cm=200, sensor_id=2)))
    (out,) = stage.process(p, start + 1.0)
    assert not out.changed and out.steady_until_s == pytest.approx(start + 5.0, abs=1e-5)  # then the bias begins
    # A sensor no rule names is forwarded as it came, for good: that too is a verdict to repeat.
    (out,) = stage.process(packet(pack(distance(cm=200, sensor_id=7))), start + 1.0)
    assert not out.changed and out.steady_until_s == math.inf


def test_dropped_delayed_and_untargeted_frames_are_not_repeated() -> None:
    stage = staged(prof(ds("drop", 1), ds("delay", 2, delay_s=0.3)))
    assert stage.memo_fields == {}
    now = time.monotonic()
    p = packet(pack(distance(sensor_id=1)))
    assert stage.process(p, now) == [] and p.steady_until_s is None
    p = packet(pack(distance(sensor_id=2)))
    assert stage.process(p, now) == [p] and p.release_s > now and p.steady_until_s is None
    stage = staged(prof(ds("bias", 1, offset_m=0.5)))
    p = packet(pack(heartbeat()))
    assert stage.process(p, now) == [p] and p.steady_until_s is None


def test_a_plugin_primitive_that_does_not_say_it_is_pure_is_never_repeated() -> None:
    """The example plugin's moving_bias (examples/plugin, installed by scripts/setup.sh as an outside package)
    keeps state and reads the position: the stage offers nothing, and a frame it rewrote is not marked."""
    stage = staged(prof(ds("moving_bias", 1, offset=0.5)))
    assert stage.memo_fields == {}
    p = packet(pack(distance(sensor_id=1)))
    (out,) = stage.process(p, time.monotonic())
    assert out.steady_until_s is None


def test_a_carrier_still_watched_is_not_offered_until_seen() -> None:
    """relative_alt biased: GLOBAL_POSITION_INT is also a carrier of the altitude the profile leaves true, which
    the stage must see once; until then it is not in memo_fields."""
    stage = staged(prof({"target": {"message": "GLOBAL_POSITION_INT", "field": "relative_alt"}, "kind": "bias",
                         "offset_m": 1.0}))  # fmt: skip
    engine = stage.slot.engine
    assert engine is not None and GLOBAL_POSITION_INT in engine.memo_fields
    assert GLOBAL_POSITION_INT in stage.slot.watching and stage.memo_fields == {}
    before = stage.memo_fields
    assert stage.memo_fields is before  # the same dict while nothing changed
    p = packet(pack(global_position()))
    (out,) = stage.process(p, time.monotonic())
    assert GLOBAL_POSITION_INT not in stage.slot.watching
    assert stage.memo_fields == {GLOBAL_POSITION_INT: "time_boot_ms"} and stage.memo_fields is not before
    assert out.changed and out.steady_until_s == math.inf


def test_memo_token_changes_with_the_engine_and_its_activation() -> None:
    slot = AttackSlot(1)
    stage = AttackStage(slot)
    assert stage.memo_token is None and stage.memo_fields == {}
    profile = prof(ds("bias", 1, offset_m=0.5))
    slot.apply(profile, "memo.yaml")
    first = stage.memo_token
    assert first is not None and stage.memo_token is first and stage.memo_token == first
    slot.apply(profile, "memo.yaml")  # the same profile again: another engine, its clock restarted
    second = stage.memo_token
    assert second != first
    assert slot.engine is not None
    slot.engine.activate(time.monotonic())
    assert stage.memo_token != second
    slot.apply(None, "memo.yaml")
    assert stage.memo_token is None and stage.memo_fields == {}

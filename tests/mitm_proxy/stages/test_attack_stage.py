"""The attack stage on its own and in the pipeline, against a reference run of the same engine."""

from __future__ import annotations

import struct
import time
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from attack_profiles.engine import Engine
from attack_profiles.profile import Profile, parse_profile
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import (
    DISTANCE_SENSOR,
    HEARTBEAT,
    LOCAL_POSITION_NED,
    distance,
    frames,
    pack,
    parse_all,
)

DOWN, UP = Direction.DOWNLINK, Direction.UPLINK


def prof(*rules: dict[str, Any], name: str = "p") -> Profile:
    return parse_profile({"name": name, "rules": list(rules)}, f"{name}.yaml")


def ds(kind: str, sensor_id: Any = 0, **kw: Any) -> dict[str, Any]:
    target = {"message": "DISTANCE_SENSOR", "sensor_id": sensor_id}
    for key in ("direction", "field"):
        if key in kw:
            target[key] = kw.pop(key)
    return {"target": target, "kind": kind, **kw}


def packet(frame: bytes, direction: Direction = DOWN) -> Packet:
    ((h, raw),) = split(frame).frames
    return Packet(raw, h, direction, 0, time.monotonic())


def test_inactive_without_a_profile_and_when_bypassed() -> None:
    slot = AttackSwitch(AttackSlot(1))
    stage = AttackStage(slot.slot)
    assert stage.name == "attack" and not stage.active and stage.message_ids == frozenset()
    slot.offer(prof(ds("bias", offset_m=1.0)))
    # the profile's message, and ArduPilot's RANGEFINDER (173) until the vehicle is seen sending one or not
    assert stage.active and stage.message_ids == frozenset({DISTANCE_SENSOR, 173}) and slot.slot.watching == {173}
    stage.active = False
    assert not stage.active and not stage.enabled
    assert AttackStage(slot.slot, active=False).active is False


def test_rewrite_notes_the_rule_and_keeps_the_packet() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("bias", sensor_id=3, offset_m=0.5), name="wall"))
    stage = AttackStage(slot.slot)
    p = packet(pack(distance(cm=200, sensor_id=3)))
    (out,) = stage.process(p, time.monotonic())
    assert out is p and p.changed and p.fields is not None and p.fields["current_distance"] == 250
    assert p.notes == ["attack:wall:rules[0]"]


def test_untouched_frame_is_not_marked_changed() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("bias", sensor_id=3, offset_m=0.5)))
    p = packet(pack(distance(cm=200, sensor_id=4)))
    assert AttackStage(slot.slot).process(p, time.monotonic()) == [p]
    assert not p.changed and p.notes == []


def test_clamped_values_are_noted() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("bias", offset_m=1000.0, out_of_range="attack")))  # past the sensor's max: wire range
    p = packet(pack(distance(cm=60000)))
    (out,) = AttackStage(slot.slot).process(p, time.monotonic())
    assert out.fields is not None and out.fields["current_distance"] == 65535
    assert "clamped:current_distance" in out.notes


def test_drop_and_delay() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("drop", sensor_id=1), ds("delay", sensor_id=2, delay_s=0.3)))
    stage = AttackStage(slot.slot)
    now = time.monotonic()
    assert stage.process(packet(pack(distance(sensor_id=1))), now) == []
    p = packet(pack(distance(sensor_id=2)))
    (out,) = stage.process(p, now)
    assert out is p and not p.changed and abs(p.release_s - (now + 0.3)) < 1e-9


def test_uplink_rules_see_only_uplink() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("bias", offset_m=1.0, direction="uplink")))
    stage = AttackStage(slot.slot)
    now = time.monotonic()
    down, up = packet(pack(distance(cm=100))), packet(pack(distance(cm=100)), UP)
    stage.process(down, now)
    stage.process(up, now)
    assert not down.changed and up.changed


def test_cleared_between_check_and_process_passes_the_frame() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("bias", offset_m=1.0)))
    stage = AttackStage(slot.slot)
    slot.offer(None)
    p = packet(pack(distance()))
    assert stage.process(p, time.monotonic()) == [p] and p.fields is None


def test_ramp_follows_the_profile_clock() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(prof(ds("ramp", rate_per_s=1.0, start_s=0.0)))
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    start = time.monotonic()
    slot.engine.activate(start)  # restart the profile clock at a known instant
    values = []
    for dt in (0.0, 1.0, 2.5):
        (o,) = pipe.feed(pack(distance(cm=300)), DOWN, start + dt)
        values.append(parse_all(o.data)[0].current_distance)
    assert values == [300, 400, 550]


# -- the pipeline with an active profile, fuzzed -----------------------------------------------------------

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
PROFILE = prof(
    ds("bias", sensor_id={"first": 0, "last": 9}, offset_m=1.25),
    {"target": {"message": "LOCAL_POSITION_NED", "field": "x"}, "kind": "bias", "offset_m": -2.0},
    ds("drop", sensor_id=20),
)


@FUZZ
@given(
    st.lists(
        st.one_of(
            frames(),
            st.builds(
                lambda c, i: pack(distance(cm=c, sensor_id=i)),
                st.integers(0, 65535),
                st.sampled_from([0, 5, 9, 10, 20]),
            ),
        ),
        min_size=1,
        max_size=12,
    ),
    st.binary(max_size=6),
)
def test_fuzz_untargeted_byte_exact_targeted_as_the_engine_says(parts: list[bytes], junk: bytes) -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(PROFILE)
    reference = Engine(PROFILE)
    now = time.monotonic()
    reference.activate(now)
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    out = pipe.feed(junk.join(parts), DOWN, now)
    sent = b"".join(o.data for o in out)
    got = split(sent).frames
    expected: list[bytes | dict[str, Any]] = []
    for frame in parts:
        ((h, raw),) = split(frame).frames
        if h.msgid not in (DISTANCE_SENSOR, LOCAL_POSITION_NED) or h.signed:
            expected.append(raw)
            continue
        (msg,) = parse_all(raw)
        fields = {n: getattr(msg, n) for n in msg.fieldnames}
        action = reference.process(now, h.msgid, fields, DOWN, h.sysid, h.compid)
        if action.drop:
            continue
        expected.append(fields | (action.fields or {}))
    # Junk between frames may itself parse as an unknown-id frame: compare only our frames.
    ours = [(h, raw) for h, raw in got if h.msgid in (HEARTBEAT, DISTANCE_SENSOR, LOCAL_POSITION_NED, 33, 253, 30)]
    assert len(ours) == len(expected)
    for (_h, raw), want in zip(ours, expected, strict=True):
        if isinstance(want, bytes):
            assert raw == want
        else:
            (msg,) = parse_all(raw)
            for name, value in want.items():
                if isinstance(value, float):  # the wire carries float32
                    value = struct.unpack("<f", struct.pack("<f", value))[0]
                got_value = getattr(msg, name)
                assert got_value == value or (value != value and got_value != got_value), name

"""The signing policy of the proxy's pipeline: what it does with signed frames, with and without the key.

The signing primitives themselves are tested in tests/mavframe/test_signing.py.
"""

from __future__ import annotations

import logging
import time

import pytest

from attack_profiles.profile import parse_profile
from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction, Packet
from mavframe.signing import Signer
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import TEST_KEY, distance, heartbeat, mav, mavlink, pack, read_strict, signed_mav

DOWN = Direction.DOWNLINK


# -- pipeline policy -----------------------------------------------------------------------------------


def attacked_pipeline(signer: Signer | None) -> tuple[Pipeline, LinkStats]:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(parse_profile({"name": "b", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                                      "kind": "bias", "offset_m": 1.0}]}, "b.yaml"))  # fmt: skip
    stats = LinkStats(1)
    return Pipeline(0, [AttackStage(slot.slot)], stats=stats, signer=signer), stats


def test_without_a_key_signed_frames_are_left_alone_and_counted() -> None:
    pipe, stats = attacked_pipeline(None)
    m = signed_mav()
    d, hb = pack(distance(cm=500), m), pack(heartbeat(), m)
    (out,) = pipe.feed(d + hb, DOWN, time.monotonic())
    assert out.data == d + hb
    s = stats[DOWN]
    assert (s.signed, s.signed_untouched, s.rewritten) == (2, 1, 0)


def test_without_a_key_the_attack_says_so_once_per_sending_system(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 27: one warning per stage and system in the log, one per system in the slot's state."""
    pipe, _stats = attacked_pipeline(None)
    slot = pipe.stages[0].slot  # type: ignore[attr-defined]
    one, two = signed_mav(sysid=1), signed_mav(sysid=2)
    for _ in range(10):
        pipe.feed(pack(distance(cm=500), one) + pack(distance(cm=500), two) + pack(heartbeat(), one), DOWN, 0.0)
    said = [r for r in caplog.records if r.getMessage() == "attack.signed_no_key"]
    assert sorted(r.sysid for r in said) == [1, 2]  # type: ignore[attr-defined]
    assert all(r.levelno == logging.WARNING and "--signing-key" in r.detail for r in said)  # type: ignore[attr-defined]
    assert [w.split(" signs")[0] for w in _signing(slot.warnings)] == ["attack.signed_no_key: system 1",
                                                                  "attack.signed_no_key: system 2"]  # fmt: skip
    AttackSwitch(slot).offer(None)
    assert slot.warnings == []  # cleared with the profile


def test_a_key_or_unsigned_frames_raise_no_warning(caplog: pytest.LogCaptureFixture) -> None:
    keyed, _ = attacked_pipeline(Signer(TEST_KEY))
    keyed.feed(pack(distance(cm=500), signed_mav()), DOWN, time.monotonic())
    plain, _ = attacked_pipeline(None)
    plain.feed(pack(distance(cm=500), mav(1)), DOWN, time.monotonic())
    assert not [r for r in caplog.records if "signed_no_key" in r.getMessage()]
    keyed_slot, plain_slot = keyed.stages[0].slot, plain.stages[0].slot  # type: ignore[attr-defined]
    assert _signing(keyed_slot.warnings) == _signing(plain_slot.warnings) == []


def test_with_a_key_signed_frames_are_verified_rewritten_and_resigned() -> None:
    pipe, stats = attacked_pipeline(Signer(TEST_KEY))
    m = signed_mav()
    d, hb = pack(distance(cm=500), m), pack(heartbeat(), m)
    bad = bytearray(pack(distance(cm=500), m))
    bad[-2] ^= 0xFF
    (out,) = pipe.feed(d + bytes(bad) + hb, DOWN, time.monotonic())
    msgs = read_strict(out.data)
    assert [x.get_type() for x in msgs] == ["DISTANCE_SENSOR", "HEARTBEAT"]
    assert msgs[0].current_distance == 600
    assert out.data.endswith(hb)
    s = stats[DOWN]
    assert (s.rewritten, s.resigned, s.bad) == (1, 1, {"bad_signature": 1})
    (again,) = pipe.feed(hb + pack(heartbeat(), m), DOWN, time.monotonic())  # replayed hb is refused
    assert len(read_strict(again.data)) == 1 and stats[DOWN].bad["stale_signature"] == 1


def test_with_a_key_unsigned_frames_pass_and_rewrites_stay_unsigned() -> None:
    pipe, stats = attacked_pipeline(Signer(TEST_KEY))
    d = pack(distance(cm=500))
    (out,) = pipe.feed(d, DOWN, time.monotonic())
    ((h, _),) = split(out.data).frames
    assert not h.signed and stats[DOWN].rewritten == 1 and stats[DOWN].resigned == 0


class InjectV1:
    """A stage that injects a MAVLink 1 frame (which cannot carry a signature)."""

    name = "v1"
    active = True
    message_ids = frozenset({0})

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        frame = pack(heartbeat(), v1=True)
        ((h, raw),) = split(frame).frames
        return [pkt, Packet(raw, h, pkt.direction, 0, now_s, injected=True)]


def test_with_a_key_injected_frames_are_signed_unless_they_cannot_be() -> None:
    stats = LinkStats(1)
    signer = Signer(TEST_KEY, link_id=5)
    beacon_fields = {"type": 2, "autopilot": 12, "base_mode": 1, "custom_mode": 0, "system_status": 4,
                     "mavlink_version": 3}  # fmt: skip

    class InjectV2(InjectV1):
        def process(self, pkt: Packet, now_s: float) -> list[Packet]:
            return [pkt, codec.build("HEARTBEAT", beacon_fields, sysid=1, compid=1, seq=0, direction=DOWN,
                                     link=0, now_s=now_s)]  # fmt: skip

    pipe = Pipeline(0, [InjectV2()], stats=stats, signer=signer)
    (out,) = pipe.feed(pack(heartbeat()), DOWN, time.monotonic())
    frames = split(out.data).frames
    assert [h.signed for h, _ in frames] == [False, True] and frames[1][1][-13] == 5
    assert Signer(TEST_KEY).verify(frames[1][1]) is None
    pipe = Pipeline(0, [InjectV1()], stats=stats, signer=signer)
    (out,) = pipe.feed(pack(heartbeat()), DOWN, time.monotonic())
    assert [h.version for h, _ in split(out.data).frames] == [2, 1]
    assert stats[DOWN].bad == {"encode_error": 1} and stats[DOWN].injected == 2 and stats[DOWN].resigned == 1


def _signing(warnings: list[str]) -> list[str]:
    """The signing warnings among a state's (a DISTANCE_SENSOR profile also says RANGEFINDER stays true)."""
    return [w for w in warnings if w.startswith("attack.signed_no_key")]


def test_a_signed_true_copy_is_seen_and_not_taken_for_a_targeted_frame() -> None:
    """A signed RANGEFINDER beside a DISTANCE_SENSOR profile (no key): the twin is warned about, once, and the
    signed-frame warning names what the profile targets, not the twin it only watched for."""
    pipe, stats = attacked_pipeline(None)
    slot = pipe.stages[0].slot  # type: ignore[attr-defined]
    m = signed_mav()
    twin = pack(mavlink.MAVLink_rangefinder_message(5.0, 1.0), m)
    for _ in range(5):
        (out,) = pipe.feed(twin, DOWN, time.monotonic())
        assert out.data == twin
    assert stats[DOWN].signed_untouched == 1  # the first only: then it is no longer watched
    assert _signing(slot.warnings) == []
    (copy,) = [w for w in slot.warnings if w.startswith("attack.true_copy: ")]
    assert "RANGEFINDER.distance still carries the true value" in copy
    pipe.feed(pack(distance(cm=500), m), DOWN, time.monotonic())
    (signed,) = _signing(slot.warnings)
    assert "(DISTANCE_SENSOR among them)" in signed

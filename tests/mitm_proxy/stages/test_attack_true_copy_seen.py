"""The attack.true_copy warning says only what this vehicle sends (issue 36), and knows the direction (issue 33).

Real streams through one link's pipeline with the attack stage: flightsim (which never sends RANGEFINDER)
and a recorded ArduCopter flight (which does). A DISTANCE_SENSOR profile warns about RANGEFINDER on the
second only, once, when the first RANGEFINDER arrives; the same rule toward the vehicle warns about nothing
and says once, at install, that the autopilot reports the lie.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import pytest

from attack_profiles.profile import parse_profile
from mavframe import tlog
from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.quantity_streams import ARDUPILOT_TLOG, flightsim_frames

RANGEFINDER = 173


def slot_for(target: dict[str, Any]) -> AttackSlot:
    slot = AttackSwitch(AttackSlot(1))
    rule = {"target": {"message": "DISTANCE_SENSOR", **target}, "kind": "bias", "offset": 2.0}
    state = slot.offer(parse_profile({"name": "p", "rules": [rule]}, "p.yaml"))
    assert state.ok, state.error
    return slot


def run(slot: AttackSlot, frames: list[bytes]) -> list[bytes]:
    """Each frame as its own datagram, toward the ground; the frames that leave."""
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    out: list[bytes] = []
    now = time.monotonic()
    for raw in frames:
        for item in pipe.feed(raw, Direction.DOWNLINK, now):
            out += [r for _h, r in split(item.data).frames]
    return out


def said(caplog: pytest.LogCaptureFixture, event: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.getMessage() == event]


def ardupilot() -> list[bytes]:
    return [e.raw for e in tlog.read(ARDUPILOT_TLOG) if e.header.sysid == 1]


@pytest.mark.timeout(60)
def test_on_the_benchs_own_simulator_nothing_is_said_about_rangefinder(caplog: pytest.LogCaptureFixture) -> None:
    frames = flightsim_frames(4.0)
    caplog.set_level(logging.INFO)
    for target in ({}, {"sensor_id": 0}):
        slot = slot_for(target)
        out = run(slot, frames)
        assert len(out) == len(frames)
        assert slot.state.warnings == [] and slot.slot.watching == {RANGEFINDER}  # still waiting: never sent
        assert slot.state.directions == ["downlink"]
    assert said(caplog, "attack.true_copy") == []


def test_in_front_of_ardupilot_the_twin_is_said_once_when_it_arrives(caplog: pytest.LogCaptureFixture) -> None:
    frames = ardupilot()
    first = next(i for i, raw in enumerate(frames) if split(raw).frames[0][0].msgid == RANGEFINDER)
    slot = slot_for({"sensor_id": 0})
    caplog.set_level(logging.INFO)
    run(slot, frames[:first])
    assert slot.state.warnings == [] and said(caplog, "attack.true_copy") == []
    out = run(slot, frames[first:])
    (warning,) = slot.state.warnings
    assert warning.startswith("attack.true_copy: rules[0] rewrite rangefinder distance in DISTANCE_SENSOR; "
                              "RANGEFINDER.distance still carries the true value")  # fmt: skip
    assert "if the vehicle sends" not in warning  # it does: no condition
    (record,) = said(caplog, "attack.true_copy")  # once, though ArduPilot sends RANGEFINDER at 10 Hz
    assert record.warning == warning.removeprefix("attack.true_copy: ")  # type: ignore[attr-defined]
    # once seen, RANGEFINDER is no longer handed to the stage: only the profile's own message is
    assert slot.slot.watching == frozenset() and slot.slot.message_ids == slot.engine.message_ids  # type: ignore[union-attr]
    sent = {raw for raw in frames[first:] if split(raw).frames[0][0].msgid == RANGEFINDER}
    assert sent <= set(out)  # RANGEFINDER frames pass byte for byte
    # the vehicle is known to send RANGEFINDER: a new profile is warned about at once
    again = slot.offer(parse_profile({"name": "q", "rules": [{"target": {"message": "DISTANCE_SENSOR"},
                                                              "kind": "bias", "offset": 1.0}]}, "q.yaml"))  # fmt: skip
    assert len(again.warnings) == 1


def test_anchor_links_leave_no_rangefinder_twin_even_in_front_of_ardupilot() -> None:
    slot = slot_for({"sensor_id": [11, 14]})
    run(slot, ardupilot())
    assert slot.state.warnings == [] and slot.slot.watching == frozenset()  # nothing to watch for


def test_toward_the_vehicle_no_twin_is_warned_and_the_echo_is_noted_once(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    slot = slot_for({"direction": "uplink", "sensor_id": 0})
    frames = ardupilot()
    out = run(slot, frames)
    assert out == frames  # toward the ground nothing changes, byte for byte
    assert slot.state.warnings == [] and said(caplog, "attack.true_copy") == []
    (note,) = said(caplog, "attack.vehicle_reports")
    assert "reports the lie itself" in note.note  # type: ignore[attr-defined]
    assert slot.state.directions == ["uplink"]
    (applied,) = said(caplog, "attack.applied")
    assert applied.changes == "toward the vehicle" and applied.directions == "uplink"  # type: ignore[attr-defined]

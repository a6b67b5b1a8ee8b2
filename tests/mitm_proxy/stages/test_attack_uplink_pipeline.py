"""A command toward the vehicle rewritten by the real pipeline and attack stage, everything else byte for byte."""

from __future__ import annotations

import struct
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles import library
from mavframe import codec
from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.frames_support import parse_all

UP = Direction.UPLINK


def _frame(message: str, seq: int, **fields: Any) -> bytes:
    """A frame as a ground station would send it (sysid 255), built by the proxy's own codec."""
    cls = codec.BY_NAME[message]
    zeros = {n: ("" if t == "char" else 0) for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)}
    return codec.build(message, {**zeros, **fields}, sysid=255, compid=190, seq=seq, direction=UP, link=0,
                       now_s=0.0).raw  # fmt: skip


def _command(seq: int, command: int, **params: float) -> bytes:
    return _frame("COMMAND_LONG", seq, target_system=1, target_component=1, command=command, **params)


def test_takeoff_to_5_m_leaves_the_proxy_as_12_m_and_nothing_else_changes() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(library.load("takeoff-altitude"))
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    frames = [
        _frame("HEARTBEAT", 0, type=6, autopilot=8, mavlink_version=3),
        _command(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, param1=1.0, param7=5.0),
        _command(2, mavlink.MAV_CMD_NAV_TAKEOFF, param7=5.0),
        _frame("PARAM_SET", 3, target_system=1, param_id="RTL_ALT", param_value=1.5e3, param_type=9),
        _command(4, mavlink.MAV_CMD_NAV_TAKEOFF, param1=0.5, param4=90.0, param7=5.0),
    ]
    out = pipe.feed(b"".join(frames), UP, time.monotonic())  # the profile's clock started when it was offered
    sent = split(b"".join(o.data for o in out)).frames
    assert [h.seq for h, _ in sent] == [0, 1, 2, 3, 4]
    for k, (_, raw) in enumerate(sent):
        if k not in (2, 4):
            assert raw == frames[k], k  # untargeted, or a command the where rejects: byte for byte
    for k in (2, 4):
        (before,), (after,) = parse_all(frames[k]), parse_all(sent[k][1])
        assert before.param7 == 5.0 and after.param7 == 12.0
        assert after.to_dict() == {**before.to_dict(), "param7": 12.0}
        # Only param7's four bytes (payload offset 24) and the CRC differ; header and sequence stay.
        header = 10
        lo, hi = header + 24, header + 28
        assert sent[k][1][:lo] == frames[k][:lo] and sent[k][1][hi:-2] == frames[k][hi:-2]
        assert struct.unpack("<f", sent[k][1][lo:hi]) == (12.0,)
    assert pipe.stats.directions[UP].frames_out == 5


def test_the_same_command_toward_the_ground_is_left_alone() -> None:
    slot = AttackSwitch(AttackSlot(1))
    slot.offer(library.load("takeoff-altitude"))
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    frame = _command(7, mavlink.MAV_CMD_NAV_TAKEOFF, param7=5.0)
    (out,) = pipe.feed(frame, Direction.DOWNLINK, time.monotonic())
    assert out.data == frame

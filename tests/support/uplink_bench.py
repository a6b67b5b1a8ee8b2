"""Test support: one link's sans-I/O pipeline with a companion feeding the vehicle and the vehicle reporting back.

The attack stage holds a profile and, optionally, the secure stage follows it; a companion (sysid 1, compid 197)
sends toward the vehicle and the vehicle (sysid 1, compid 1) toward the ground. :class:`Run` keeps every frame that
went in and came out, per direction, for the tests of the secure stage on the uplink.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from attack_profiles.profile import parse_profile
from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.stage import SecureStage
from secuav_common.scenario import Scenario


@dataclass
class Run:
    up_in: list[bytes] = field(default_factory=list)  # frames the companion sent toward the vehicle
    up_out: list[bytes] = field(default_factory=list)  # frames the autopilot received
    down_in: list[bytes] = field(default_factory=list)
    down_out: list[bytes] = field(default_factory=list)


class UplinkBench:
    """The pipeline of vehicle 1 under ``profile`` (a profile document), with ``secure`` after the attack stage."""

    def __init__(self, scenario: Scenario, profile: dict[str, Any] | str, source: str,
                 secure: SecureConfig | None) -> None:  # fmt: skip
        slot = AttackSwitch(AttackSlot(1, scenario))
        assert slot.offer(parse_profile(profile, source)).ok
        stages: list[Any] = [AttackStage(slot.slot)]
        if secure is not None:
            stages.append(SecureStage(secure, scenario, 1))
        self.pipe = Pipeline(0, stages, stats=LinkStats(1))
        self.companion = mavlink.MAVLink(None, srcSystem=1, srcComponent=197)
        self.vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.run = Run()

    def send(self, mav: mavlink.MAVLink, msg: mavlink.MAVLink_message, direction: Direction, t_s: float) -> None:
        """One frame, its own datagram, through the pipeline; what went in and what came out are kept."""
        raw = bytes(msg.pack(mav))
        got = [r for o in self.pipe.feed(raw, direction, t_s) for _h, r in split(o.data).frames]
        if direction is Direction.UPLINK:
            self.run.up_in.append(raw)
            self.run.up_out += got
        else:
            self.run.down_in.append(raw)
            self.run.down_out += got

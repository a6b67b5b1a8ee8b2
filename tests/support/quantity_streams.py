"""Real streams through one link's pipeline with the attack stage, for the quantity-target tests: the recorded
ArduCopter flight (tests/data) and a short flightsim run on loopback."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from pathlib import Path

from attack_profiles.profile import parse_profile
from flightsim.runner import RunConfig, SimRunner
from mavframe import tlog
from mavframe.frames import split
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint
from tests.support.quantity_check import Checker, Offsets, Report

ARDUPILOT_TLOG = Path(__file__).resolve().parents[1] / "data" / "ardupilot-copter-guided.tlog"
OFFSETS = Offsets(range_m=5.0, range_ids=frozenset({0}), up_m=3.0, north_m=7.0, east_m=-4.0)


def through_stage(frames: list[tuple[bytes, Direction]], offsets: Offsets) -> list[bytes]:
    """Each frame as its own datagram through one link's pipeline with the attack stage; the frames that leave."""
    slot = AttackSwitch(AttackSlot(1))
    state = slot.offer(parse_profile(offsets.profile(), "quantities.yaml"))
    assert state.ok, state.error
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    out: list[bytes] = []
    now = time.monotonic()
    for raw, direction in frames:
        for item in pipe.feed(raw, direction, now):
            out += [r for _h, r in split(item.data).frames]
    return out


def recorded_through_stage(path: Path) -> Report:
    """A recorded .tlog (the ground station's frames uplink, the rest downlink) through the stage, checked."""
    frames = [(e.raw, Direction.UPLINK if e.header.sysid == 255 else Direction.DOWNLINK) for e in tlog.read(path)]
    return Checker(OFFSETS).check([raw for raw, _ in frames], through_stage(frames, OFFSETS))


def flightsim_frames(duration_s: float = 6.0) -> list[bytes]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    port = sock.getsockname()[1]
    got: list[bytes] = []

    async def run() -> None:
        loop = asyncio.get_running_loop()
        cfg = RunConfig(load_scenario("wall_hover"), [Endpoint("udpout", "127.0.0.1", port)], speed=4.0,
                        duration_s=duration_s)  # fmt: skip
        stop = asyncio.Event()
        async with SimRunner(cfg) as runner:
            task = asyncio.create_task(runner.run(stop))
            while not task.done():
                with contextlib.suppress(TimeoutError):
                    got.append(await asyncio.wait_for(loop.sock_recv(sock, 65536), 0.2))
            await task

    try:
        asyncio.run(run())
    finally:
        sock.close()
    return [raw for datagram in got for _h, raw in split(datagram).frames]

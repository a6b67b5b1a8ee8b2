"""What a watching console costs the forwarding path (issue 13: nothing may slow it).

Feeds a realistic downlink mix through one link's pipeline (no profile, the
common case; and with a bias profile on sensor 0): HEARTBEAT, ATTITUDE,
LOCAL_POSITION_NED and six DISTANCE_SENSOR frames per round, one frame per
datagram. Alternates the pipeline without a readings tap (no console: the
baseline) and with one (a console watches), and prints microseconds per frame
and the ratio to the baseline measured in the same round. Figures only.

    .venv/bin/python benchmarks/readings_bench.py [--rounds 20000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

from pymavlink.dialects.v20 import common as mavlink2

from attack_profiles.profile import parse_profile
from mavframe.packet import Direction
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.readings import ReadingsTap
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot

BIAS = {"name": "bias", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0}, "kind": "bias",
                                   "offset_m": 1.0}]}  # fmt: skip


def _frames() -> list[bytes]:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = [
        mav.heartbeat_encode(2, 12, 129, 0, 4, 3).pack(mav),
        mav.attitude_encode(1, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav),
        mav.local_position_ned_encode(1, 1.0, 2.0, -2.5, 0, 0, 0).pack(mav),
    ]
    out += [mav.distance_sensor_encode(1, 10, 4000, 250 + i, 0, i, 0, 0).pack(mav) for i in range(6)]
    return out


def _cost(profile: bool, tap: bool, frames: list[bytes], rounds: int) -> float:
    slot = AttackSwitch(AttackSlot(1))
    if profile:
        slot.offer(parse_profile(BIAS, "bench"))
    pipe = Pipeline(0, [AttackStage(slot.slot)], stats=LinkStats(1))
    watcher = ReadingsTap(1)
    if tap:
        pipe.attach(watcher)
    feed, down = pipe.feed, Direction.DOWNLINK
    t0 = time.perf_counter()
    for i in range(rounds):
        for frame in frames:
            feed(frame, down, t0)
        if tap and i % 200 == 0:
            watcher.take()  # the 10 Hz publisher empties it
    return (time.perf_counter() - t0) / (rounds * len(frames)) * 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=20_000)
    p.add_argument("--repeat", type=int, default=5)
    args = p.parse_args()
    frames = _frames()
    print(f"{'case':34s} {'us/frame':>9s} {'ratio':>6s}")
    for profile in (False, True):
        times: dict[bool, list[float]] = {False: [], True: []}
        for _ in range(args.repeat):
            for tap in (False, True):
                times[tap].append(_cost(profile, tap, frames, args.rounds))
        base = statistics.median(times[False])
        for tap in (False, True):
            med = statistics.median(times[tap])
            name = f"{'bias on sensor 0' if profile else 'no profile'}, {'console watching' if tap else 'no console'}"
            print(f"{name:34s} {med:9.2f} {med / base:6.2f}")


if __name__ == "__main__":
    main()

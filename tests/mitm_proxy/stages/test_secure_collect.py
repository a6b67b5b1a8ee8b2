"""How the secure stage groups a vehicle's DISTANCE_SENSOR frames into the sets it steps on (collect.py).

The sets must hold readings of one instant: two honest sensors read at moments 50 ms apart disagree by
0.05 m per m/s of motion, which the estimators judge as an attack. flightsim sends its wall group in id
order, four sensors at 20 Hz and the sonar (id 2) at 10 Hz, so a set that steps on the first frame
that completes it mixes bursts.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mitm_proxy.stages.secure.collect import Readings
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.layout import Layout, build_layout
from secuav_common.scenario import load_scenario

CONFIG = SecureConfig(estimator="secekf")
RATES_HZ = {0: 20, 1: 20, 2: 10, 3: 20, 4: 20}  # the wall_hover scenario's group


@pytest.fixture(scope="module")
def layout() -> Layout:
    return build_layout(CONFIG, load_scenario("wall_hover"), 1)


def frame(sid: int, stamp_ms: int, cm: int = 300) -> dict[str, int]:
    """A DISTANCE_SENSOR frame's fields, a valid reading."""
    return {"id": sid, "time_boot_ms": stamp_ms, "current_distance": cm, "min_distance": 10, "max_distance": 4000,
            "signal_quality": 100}  # fmt: skip


def distance_at(stamp_ms: int) -> float:
    return 5.0 - 1.2 * stamp_ms / 1000.0  # approaching the wall at 1.2 m/s


def fly(layout: Layout, order: list[int], seconds: float = 3.0, gap_s: float = 0.0005) -> list[np.ndarray]:
    """Feed bursts every 50 ms (each sensor when its rate says), frames ``gap_s`` apart in ``order``; the sets."""
    readings, sets = Readings(layout), []
    for stamp_ms in range(0, int(seconds * 1000), 50):
        now_s = stamp_ms / 1000.0 + 0.01  # the link's delay; the stage clock is the proxy's
        for sid in order:
            if stamp_ms % (1000 // RATES_HZ[sid]):
                continue
            now_s += gap_s
            readings.take_range(layout, frame(sid, stamp_ms, round(distance_at(stamp_ms) * 100)), now_s)
            if readings.due(CONFIG, now_s) is not None:
                sets.append(readings.job(CONFIG, layout, now_s).z.copy())
    return sets


def test_a_set_holds_one_burst_when_the_slow_sensor_comes_mid_burst(layout: Layout) -> None:
    sets = fly(layout, [0, 1, 2, 3, 4])
    assert len(sets) >= 25  # one set per sonar burst: 10 Hz for 3 s, less the first
    for z in sets[1:]:
        assert np.ptp(z) <= 0.011, z  # every reading of one instant (cm rounding); mixed bursts: 0.06 m apart


def test_a_whole_burst_steps_at_once_with_no_sensor_awaited_past_it(layout: Layout) -> None:
    # After the 50 ms burst (no sonar) and the 100 ms one (all five), every sensor's next reading is due after
    # 100 ms: nothing is awaited, the set is complete on the burst's last frame.
    readings = Readings(layout)
    for stamp_ms in (0, 50, 100):
        for sid in (0, 1, 2, 3, 4):
            if stamp_ms % (1000 // RATES_HZ[sid]) == 0:
                readings.take_range(layout, frame(sid, stamp_ms), stamp_ms / 1000.0)
        if stamp_ms == 0:
            readings.job(CONFIG, layout, 0.0)
    assert readings.due(CONFIG, 0.1) == "complete"  # the 100 ms burst is all in: step at once


@settings(max_examples=30, deadline=None)
@given(order=st.permutations([0, 1, 2, 3, 4]))
def test_any_frame_order_in_a_burst_gives_sets_of_one_instant(layout: Layout, order: list[int]) -> None:
    sets = fly(layout, list(order), seconds=1.5)
    assert sets and all(np.ptp(z) <= 0.011 for z in sets[1:])


def test_a_sensor_that_stops_delays_a_set_by_max_wait_at_most(layout: Layout) -> None:
    readings, steps = Readings(layout), []
    for stamp_ms in range(0, 2000, 50):
        now_s = stamp_ms / 1000.0
        for sid in (0, 1, 2, 3, 4):
            if stamp_ms % (1000 // RATES_HZ[sid]) or (sid == 4 and stamp_ms >= 1000):  # id 4 falls silent at 1 s
                continue
            readings.take_range(layout, frame(sid, stamp_ms), now_s)
        for tick in np.arange(now_s, now_s + 0.05, 0.005):  # the stage's own polling between bursts
            if readings.due(CONFIG, float(tick)) is not None:
                steps.append(float(tick))
                readings.job(CONFIG, layout, float(tick))
    gaps = np.diff([t for t in steps if t > 1.0])
    assert gaps.size > 5 and gaps.max() <= 0.1 + CONFIG.max_wait_s + 1e-6

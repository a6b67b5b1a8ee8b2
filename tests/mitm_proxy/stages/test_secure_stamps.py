"""The secure stage's reading clock (stamps.py): a sender's time_boot_ms mapped onto the proxy's clock.

What it promises: a reading is never placed after its arrival; under delays in [d0, d0 + J] every reading is placed
within [d0, d0 + J] of when it was taken, never further off than its arrival would place it; a reboot or a time
jump re-anchors (logged, counted); a reading without a stamp is timed at its arrival, counted.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mitm_proxy.stages.secure.collect import Readings
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.layout import build_layout
from mitm_proxy.stages.secure.stamps import CONFIRM, JUMP_S, StampClock
from secuav_common.scenario import load_scenario

SRC = (1, 1)
C_S = 1000.0  # the proxy's clock when the sender booted


def deliver(clock: StampClock, stamps_ms: list[int], delays_s: list[float], c_s: float = C_S) -> list[tuple]:
    """Readings taken at ``c_s + stamp`` arrive ``delay`` later, fed in arrival order; (taken, arrival, mapped)."""
    taken = [c_s + s / 1000.0 for s in stamps_ms]
    order = sorted(range(len(stamps_ms)), key=lambda k: (taken[k] + delays_s[k], k))
    out = []
    for k in order:
        arrival = taken[k] + delays_s[k]
        out.append((taken[k], arrival, clock.time_of(SRC, stamps_ms[k], arrival)))
    return out


periods = st.lists(st.integers(1, 120), min_size=2, max_size=200)


@settings(max_examples=200, deadline=None)
@given(periods=periods, d0=st.floats(0.0, 0.2), jitter=st.floats(0.0, JUMP_S * 0.9), data=st.data())
def test_bounded_jitter_places_every_reading_within_it_and_never_after_arrival(
    periods: list[int], d0: float, jitter: float, data: st.DataObject
) -> None:
    stamps = list(np.cumsum(periods) + 5000)  # booted 5 s before the first reading
    delays = [d0 + jitter * u for u in data.draw(st.lists(st.floats(0.0, 1.0), min_size=len(stamps),
                                                          max_size=len(stamps)))]  # fmt: skip
    clock = StampClock()
    for taken, arrival, mapped in deliver(clock, [int(s) for s in stamps], delays):
        assert mapped <= arrival  # never in the future
        err = mapped - taken
        assert d0 - 1e-9 <= err <= d0 + jitter + 1e-9
        assert err <= arrival - taken + 1e-9  # never worse placed than by its arrival
    assert clock.reanchors == {} and clock.stamped == len(stamps) and clock.unstamped == 0


@settings(max_examples=200, deadline=None)
@given(events=st.lists(st.tuples(st.integers(-(2**31), 2**32), st.floats(0.0, 5.0)), min_size=1, max_size=100))
def test_any_stamps_at_all_are_never_mapped_after_their_arrival(events: list[tuple[int, float]]) -> None:
    """Garbage, reboots, replays, jumps: whatever the stamps, a reading's time is at most its arrival."""
    clock, now = StampClock(), 0.0
    for stamp, gap in events:
        now += gap
        assert clock.time_of(SRC, stamp, now) <= now


def test_one_reading_of_least_delay_places_the_next_ones_to_it() -> None:
    clock = StampClock()
    delays = [0.30, 0.25, 0.02, 0.40, 0.31, 0.18, 0.22]  # the third came with the link's least delay
    out = deliver(clock, [1000 + 400 * k for k in range(len(delays))], delays)  # in order, within the window
    errors = [mapped - taken for taken, _arrival, mapped in out]
    assert errors[:2] == pytest.approx([0.30, 0.25])
    assert errors[2:] == pytest.approx([0.02] * 5)  # arrival timing: 0.40, 0.31, 0.18, 0.22 late


def test_a_burst_after_an_outage_is_placed_at_its_stamps_without_a_reanchor() -> None:
    clock = StampClock()
    stamps = [1000 + 50 * k for k in range(200)]  # 10 s at 20 Hz
    delays = [0.01] * 200
    for k in range(60, 90):  # 1.5 s of readings held, then delivered at once (arrival: up to 1.5 s too new)
        delays[k] = (1000 + 50 * 90) / 1000.0 - stamps[k] / 1000.0 + 0.01
    out = deliver(clock, stamps, delays)
    assert clock.reanchors == {}
    for taken, _arrival, mapped in out:
        assert mapped - taken == pytest.approx(0.01)


def test_a_reboot_reanchors_with_a_log_line_and_then_maps_as_before(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    clock = StampClock(name="secure-v1")
    before = deliver(clock, [10_000 + 50 * k for k in range(40)], [0.01] * 40)
    # It rebooted: 3 s down, then its clock starts again from 0, with a new delay
    after = deliver(clock, [20 + 50 * k for k in range(40)], [0.05] * 40, c_s=before[-1][0] + 3.0)
    assert clock.reanchors == {"stamp_backwards": 1} and clock.off_clock == CONFIRM - 1
    assert [m == a for _t, a, m in after[: CONFIRM - 1]] == [True] * (CONFIRM - 1)  # until confirmed: at arrival
    assert all(m - t == pytest.approx(0.05) for t, _a, m in after)
    recs = [r for r in caplog.records if r.getMessage() == "secure.clock_anchor"]
    assert [r.reason for r in recs] == ["first", "stamp_backwards"]  # type: ignore[attr-defined]
    rec = recs[1]
    assert rec.levelno == logging.WARNING and rec.sysid == 1 and rec.compid == 1  # type: ignore[attr-defined]
    assert rec.stage == "secure-v1" and rec.stamp_ms == 20 + 50 * (CONFIRM - 1)  # type: ignore[attr-defined]
    assert clock.stats()["clock_reanchors"] == 1


@settings(max_examples=150, deadline=None)
@given(uptime_s=st.floats(2.0, 600.0), down_s=st.floats(0.0, 30.0), restart_ms=st.integers(1, 400),
       delay=st.tuples(st.floats(0.0, 0.2), st.floats(0.0, 0.2)), jitter=st.floats(0.0, JUMP_S * 0.9),
       seed=st.integers(0, 2**16))  # fmt: skip
def test_any_reboot_reanchors_once_and_the_bound_holds_on_both_sides(
    uptime_s: float, down_s: float, restart_ms: int, delay: tuple[float, float], jitter: float, seed: int
) -> None:
    """Up for ``uptime_s``, down ``down_s``, its clock restarting at ``restart_ms``; another least delay after."""
    rng = np.random.default_rng(seed)
    clock = StampClock()
    last_ms = round(uptime_s * 1000)
    before = [last_ms - 50 * k for k in range(30, -1, -1)]
    after = [restart_ms + 50 * k for k in range(30)]
    c_after = C_S + last_ms / 1000.0 + down_s - restart_ms / 1000.0
    for stamps, d0, c_s in ((before, delay[0], C_S), (after, delay[1], c_after)):
        out = deliver(clock, stamps, list(d0 + jitter * rng.random(len(stamps))), c_s=c_s)
        for taken, arrival, mapped in out:
            assert mapped <= arrival and d0 - 1e-9 <= mapped - taken <= d0 + jitter + 1e-9
    assert clock.reanchors == {"stamp_backwards": 1} and clock.unstamped == 0


def test_replayed_frames_among_the_real_ones_do_not_move_the_clock() -> None:
    """An attacker replays frames recorded 5 s earlier between the vehicle's own: each is timed at its arrival and
    counted, the vehicle's readings keep their stamps."""
    clock = StampClock()
    genuine = []
    for k in range(200):  # 10 s at 20 Hz, each real reading 10 ms late
        t = 10.0 + 0.05 * k
        genuine.append(clock.time_of(SRC, round(t * 1000), C_S + t + 0.01) - (C_S + t))
        if k % 2 == 0:  # a replay after every other one
            clock.time_of(SRC, round((t - 5.0) * 1000), C_S + t + 0.02)
    assert genuine == pytest.approx([0.01] * 200) and clock.reanchors == {} and clock.off_clock == 100


def test_runs_of_replayed_frames_take_the_clock_only_while_they_last(caplog: pytest.LogCaptureFixture) -> None:
    """Runs of CONFIRM replayed frames look like a reboot: the clock follows them and the vehicle's own readings are
    timed at their arrival (as with ``reading_time: arrival``, never newer); when the replay stops, CONFIRM of its
    readings bring the clock back. The log says so at most once a second per sender, counting what it left out."""
    caplog.set_level(logging.INFO)
    clock = StampClock()
    for k in range(40):
        t = 10.0 + 0.05 * k
        clock.time_of(SRC, round(t * 1000), C_S + t + 0.01)
    for k in range(40):  # 2 s of runs of replayed frames, one real reading after each run
        t = 12.0 + 0.05 * k
        for j in range(CONFIRM):
            clock.time_of(SRC, round((t - 5.0 + 0.01 * j) * 1000), C_S + t + 0.001 * j)
        assert clock.time_of(SRC, round(t * 1000), C_S + t + 0.01) == C_S + t + 0.01  # at its arrival
    assert clock.reanchors == {"stamp_backwards": 1}
    after = [clock.time_of(SRC, round(t * 1000), C_S + t + 0.01) - (C_S + t) for t in 14.0 + 0.05 * np.arange(20)]
    assert clock.reanchors == {"stamp_backwards": 1, "stamp_ahead": 1}
    assert after[CONFIRM:] == pytest.approx([0.01] * (20 - CONFIRM))
    for k in range(40):  # 2 s of runs of either: the clock flaps, the log does not
        t = 15.0 + 0.05 * k
        for j in range(CONFIRM):
            clock.time_of(SRC, round((t - 5.0 + 0.01 * j) * 1000), C_S + t + 0.001 * j)
        for j in range(CONFIRM):
            clock.time_of(SRC, round((t + 0.01 * j) * 1000), C_S + t + 0.01 + 0.001 * j)
    assert sum(clock.reanchors.values()) > 60
    lines = [r for r in caplog.records if r.getMessage() == "secure.clock_anchor"]
    assert len(lines) <= 6 and lines[-1].unlogged > 10  # type: ignore[attr-defined]


def test_a_reading_a_little_out_of_order_is_no_reboot() -> None:
    clock = StampClock()
    deliver(clock, [1000, 1050, 1100, 1150], [0.01, 0.01, 0.20, 0.01])  # 1100 arrives after 1150
    assert clock.reanchors == {}


def test_a_clock_that_jumps_ahead_reanchors() -> None:
    clock = StampClock()
    deliver(clock, [1000 + 50 * k for k in range(20)], [0.01] * 20)
    out = deliver(clock, [60_000 + 50 * k for k in range(5)], [0.01] * 5, c_s=C_S + 1.0 - 59.0)  # 58 s ahead
    assert clock.reanchors == {"stamp_ahead": 1}
    assert [m - t for t, _a, m in out] == pytest.approx([0.01] * 5)  # at arrival until confirmed: the same here


def test_a_clock_that_falls_behind_for_good_reanchors_after_the_bound() -> None:
    """A simulator paused 5 s that keeps counting from where it stopped: its readings look 5 s old until the
    offset has been far above the least one for jump_s of arrivals; then they are placed right again."""
    clock = StampClock()
    deliver(clock, [1000 + 50 * k for k in range(20)], [0.01] * 20)
    out = deliver(clock, [2000 + 50 * k for k in range(40)], [0.01] * 40, c_s=C_S + 5.0)
    assert clock.reanchors == {"stamp_behind": 1}
    late = [m - t for t, _a, m in out]
    n_old = sum(e < -1.0 for e in late)  # placed 5 s early: the stage takes them as too old, never as newer
    assert 0 < n_old <= JUMP_S / 0.05 + 1
    assert late[-1] == pytest.approx(0.01)


def test_no_stamp_is_arrival_counted_and_arrival_mode_ignores_stamps() -> None:
    clock = StampClock()
    assert clock.time_of(SRC, 0, 5.0) == 5.0 and clock.time_of(SRC, None, 6.0) == 6.0
    assert clock.stats() == {"reading_time": "stamp", "readings_stamped": 0, "readings_unstamped": 2,
                             "readings_off_clock": 0, "clock_sources": 0, "clock_reanchors": 0,
                             "clock_reanchor_reasons": {}}  # fmt: skip
    arrival = StampClock("arrival")
    deliver(arrival, [1000, 1050, 1100], [0.3, 0.0, 0.1])
    assert arrival.time_of(SRC, 1200, 9.0) == 9.0
    assert arrival.stats()["readings_stamped"] == 0 and arrival.stats()["reading_time"] == "arrival"


def test_each_sender_has_its_own_clock() -> None:
    clock = StampClock()
    assert clock.time_of((1, 1), 10_000, 100.0) == 100.0
    assert clock.time_of((1, 197), 500, 100.01) == 100.01  # a companion booted later: no reboot of the autopilot
    assert clock.time_of((1, 1), 10_050, 100.20) == pytest.approx(100.05)
    assert clock.reanchors == {} and clock.stats()["clock_sources"] == 2


def test_the_stage_collects_each_reading_at_its_stamp_and_judges_its_age_by_it() -> None:
    """Readings (collect.py): a set's times are the readings' stamps on the proxy's clock; one held back 0.6 s is
    too old for max_age_s 0.5 by its stamp, though it just arrived (timed by arrival, it would count as fresh)."""
    def frame(sid: int, stamp_ms: int) -> dict[str, int]:
        return {"id": sid, "time_boot_ms": stamp_ms, "current_distance": 250, "min_distance": 10,
                "max_distance": 4000, "signal_quality": 100}  # fmt: skip

    jobs = {}
    for mode in ("stamp", "arrival"):
        cfg = SecureConfig(estimator="ekf", reading_time=mode)
        layout = build_layout(cfg, load_scenario("wall_hover"), 1)
        readings = Readings(layout, StampClock(mode))
        for sid in range(5):
            readings.take_range(layout, frame(sid, 1000), 100.01, SRC)  # on time: 10 ms
        readings.job(cfg, layout, 100.01)
        for sid in range(4):
            readings.take_range(layout, frame(sid, 1300), 100.41, SRC)  # 100 ms late
        readings.take_range(layout, frame(4, 1000 + 50), 100.66, SRC)  # 600 ms late
        jobs[mode] = readings.job(cfg, layout, 100.66)
    assert jobs["stamp"].times[:4] == pytest.approx([100.31] * 4)
    assert np.isnan(jobs["stamp"].z[4])  # taken 0.56 s before the step
    assert jobs["arrival"].times[:4] == pytest.approx([100.41] * 4) and jobs["arrival"].times[4] == 100.66

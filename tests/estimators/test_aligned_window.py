"""Readings one at a time with their own timestamps (issue 34, item 1; estimators.aligned): the window, the time
alignment with the motion model, sequential updates, gaps, out-of-order arrival and links too sparse for a window."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators import aligned
from estimators.aligned import Aligned, Sequential, _Window, align, coverage
from estimators.scenario_models import anchor_model
from secuav_common.scenario import load_scenario

MODEL = anchor_model(load_scenario("anchors8"), dims=2)
HEIGHT = -2.5


def _circle(t: np.ndarray, speed: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    w = speed / 1.5
    pos = np.column_stack([2.5 + 1.5 * np.cos(w * t), 2.5 + 1.5 * np.sin(w * t)])
    vel = np.column_stack([-speed * np.sin(w * t), speed * np.cos(w * t)])
    return pos, vel


def _polled(seconds: float, poll_hz: float, sigma: float, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tag polling the eight anchors one at a time: times, readings (N, 8) with one finite entry, true position."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / poll_hz)
    pos, _ = _circle(t)
    z = np.full((t.size, MODEL.p), np.nan)
    for k in range(t.size):
        a = k % MODEL.p
        z[k, a] = MODEL.h(pos[k], HEIGHT)[a] + rng.normal(0.0, sigma)
    return t, z, pos


@settings(max_examples=60, deadline=None)
@given(
    north=st.floats(0.5, 4.5),
    east=st.floats(0.5, 4.5),
    vn=st.floats(-2.0, 2.0),
    ve=st.floats(-2.0, 2.0),
    ages=st.lists(st.floats(0.0, 2.0), min_size=1, max_size=4),
)
def test_alignment_is_exact_under_constant_velocity(
    north: float, east: float, vn: float, ve: float, ages: list[float]
) -> None:
    """Readings taken along a constant-velocity path, each at its own age, come out as the ranges at the output
    time (their mean too): what the motion model promises, and nothing else is added."""
    pos, vel, t = np.array([north, east]), np.array([vn, ve]), 10.0
    times, values = [], []
    for i in range(MODEL.p):
        ts = np.array([t - a for a in ages[: 1 + i % len(ages)]])
        times.append(ts)
        values.append(np.array([MODEL.h(pos - vel * (t - tk), HEIGHT)[i] for tk in ts]))
    got = align(MODEL, t, times, values, (pos, vel), HEIGHT)
    assert np.allclose(got, MODEL.h(pos, HEIGHT), atol=1e-9)
    # Without a reference (no valid estimate yet) the readings go in as they are: their mean.
    raw = align(MODEL, t, times, values, None, HEIGHT)
    assert np.allclose(raw, [np.mean(v) for v in values])


@settings(max_examples=80, deadline=None)
@given(
    readings=st.lists(
        st.tuples(st.integers(0, 7), st.floats(0.0, 5.0).map(lambda x: round(x, 2)), st.floats(1.0, 6.0)),
        min_size=1,
        max_size=40,
    ),
    order=st.randoms(use_true_random=False),
)
def test_arrival_order_does_not_matter(readings: list[tuple[int, float, float]], order: object) -> None:
    """Out-of-order arrival within the window: the window holds the same readings in time order either way; a
    reading that arrives twice counts once."""
    ahead, shuffled = _Window(MODEL.p, 10.0), _Window(MODEL.p, 10.0)
    for link, ts, v in sorted(readings, key=lambda r: r[1]):
        z = np.full(MODEL.p, np.nan)
        z[link] = v
        ahead.add(ts, z)
    mixed = list(readings) + list(readings)  # each twice
    order.shuffle(mixed)  # type: ignore[attr-defined]
    for link, ts, v in mixed:
        z = np.full(MODEL.p, np.nan)
        z[link] = v
        shuffled.add(ts, z)
    assert ahead.t == shuffled.t and ahead.readings == shuffled.readings
    for i in range(MODEL.p):
        assert ahead.t[i] == sorted(ahead.t[i])
    ta, va = ahead.take(5.0)
    tb, vb = shuffled.take(5.0)
    for a, b, c, e in zip(ta, tb, va, vb, strict=True):
        assert np.array_equal(a, b) and np.array_equal(np.sort(c), np.sort(e))


def test_fresh_readings_are_used_once_and_a_silent_link_its_newest_again() -> None:
    win = _Window(2, 1.0)
    win.add(0.1, np.array([1.0, 5.0]))
    win.add(0.2, np.array([2.0, np.nan]))
    win.add(0.3, np.array([3.0, np.nan]))
    times, values = win.take(0.3)
    assert list(values[0]) == [1.0, 2.0, 3.0] and list(values[1]) == [5.0]
    win.add(0.4, np.array([4.0, np.nan]))
    times, values = win.take(0.4)
    assert list(values[0]) == [4.0]  # only what arrived since the last output
    assert list(values[1]) == [5.0] and list(times[1]) == [0.1] and win.reused == 1  # link 1 silent: its newest
    times, values = win.take(1.15)  # link 1's reading is now older than the window: gone
    assert values[1].size == 0 and list(values[0]) == [4.0]
    win.add(0.05, np.array([9.0, 9.0]))  # older than the window when it arrives: dropped, counted
    assert win.late == 2 and win.stats()["late_dropped"] == 2
    win.add(2.0, np.array([6.0, np.nan]))  # after the output time: kept for the next output
    assert win.take(1.5)[1][0].size in (0, 1) and list(win.take(2.0)[1][0]) == [6.0]


def _run(est: Aligned | Sequential, t: np.ndarray, z: np.ndarray, frames: np.ndarray) -> list:
    outs, j = [], 0
    for tf in frames:
        while j < t.size and t[j] <= tf + 1e-9:
            est.read(float(t[j]), z[j], HEIGHT)
            j += 1
        outs.append(est.step(float(tf), None, HEIGHT))
    return outs


@pytest.mark.parametrize("name", ["ls", "ekf", "secekf", "secopt", "rarse", "recap", "l1", "l0"])
def test_every_estimator_takes_polled_readings(name: str) -> None:
    """A tag polling one anchor at a time (16 Hz, each link at 2 Hz) while it circles at 0.3 m/s: every estimator
    starts from the window and keeps within the readings' noise; the EKF by sequential updates, the others aligned."""
    t, z, _ = _polled(30.0, 16.0, 0.05)
    est = aligned.create(name, MODEL, async_window_s=1.0)
    assert isinstance(est, Sequential if name == "ekf" else Aligned)
    assert est.processing == aligned.processing(name)
    frames = np.arange(1.0, 30.0, 1.0)
    outs = _run(est, t, z, frames)
    truth, _ = _circle(frames)
    err = np.array([np.linalg.norm(o.position_m[:2] - p) for o, p in zip(outs, truth, strict=True)])
    assert all(o.ok for o in outs[1:])
    assert float(np.sqrt(np.mean(err[3:] ** 2))) < 0.12, name
    assert est.stats()["readings"] == int(np.isfinite(z[t <= frames[-1] + 1e-9]).sum())


@settings(max_examples=6, deadline=None)
@given(
    gap_start=st.floats(8.0, 14.0),
    gap_s=st.floats(2.0, 8.0),
    name=st.sampled_from(["ekf", "secekf", "ls"]),
)
def test_a_long_gap_is_survived(gap_start: float, gap_s: float, name: str) -> None:
    """No readings for seconds: no output claims to know more than the envelope allows, and the estimate comes
    back with the readings."""
    t, z, _ = _polled(30.0, 16.0, 0.05, seed=9)
    keep = (t < gap_start) | (t > gap_start + gap_s)
    t, z = t[keep], z[keep]
    est = aligned.create(name, MODEL, async_window_s=1.0)
    frames = np.arange(0.5, 30.0, 0.5)
    outs = _run(est, t, z, frames)
    env = est.inner.envelope
    assert env is not None
    for o in outs:
        if o.ok:  # (without an estimate, e.g. started again after the gap, ok is False and the position NaN)
            assert np.isfinite(o.position_m).all()
            assert np.all(o.position_m >= env.lo - 1e-9) and np.all(o.position_m <= env.hi + 1e-9)
    truth, _ = _circle(frames)
    late = frames > gap_start + gap_s + 4.0
    err = [np.linalg.norm(o.position_m[:2] - p) for o, p, k in zip(outs, truth, late, strict=True) if k]
    assert err and max(err) < 0.4


def test_out_of_order_reading_is_brought_to_the_filters_time() -> None:
    """A reading that arrives after the filter moved past its time is moved forward by the motion model and
    applied there: no step backwards, and nearly what in-order arrival gives."""
    t, z, _ = _polled(20.0, 16.0, 0.0)
    frames = np.arange(1.0, 20.0, 1.0)
    ordered = Sequential(aligned.create("ekf", MODEL), 1.0)
    late = Sequential(aligned.create("ekf", MODEL), 1.0)
    a = _run(ordered, t, z, frames)
    swapped_t, swapped_z = t.copy(), z.copy()
    for k in range(40, t.size - 1, 7):  # every seventh reading arrives after the next one
        swapped_t[[k, k + 1]] = swapped_t[[k + 1, k]]
        swapped_z[[k, k + 1]] = swapped_z[[k + 1, k]]
    b = []
    j = 0
    for tf in frames:
        while j < t.size and swapped_t[j] <= tf + 1e-9 and t[j] <= tf + 1e-9:
            late.read(float(swapped_t[j]), swapped_z[j], HEIGHT)
            j += 1
        b.append(late.step(float(tf), None, HEIGHT))
    diffs = [np.linalg.norm(x.position_m - y.position_m) for x, y in zip(a, b, strict=True)]
    assert max(diffs) < 0.02


@settings(max_examples=60, deadline=None)
@given(
    period=st.floats(0.05, 5.0),
    window=st.floats(0.05, 5.0),
    rate=st.sampled_from([1.0, 2.0, 5.0, 10.0]),
)
def test_a_link_too_sparse_for_the_window_is_named(period: float, window: float, rate: float) -> None:
    """One link read every ``period`` s, the others at 20 Hz: refused exactly when windows of ``window`` s at the
    output rate leave it empty at more than half the outputs, the line naming it with its numbers."""
    frames = np.arange(1.0, 60.0, 1.0 / rate)
    fast = np.arange(0.0, 60.0, 0.05)
    slow = np.arange(0.013, 60.0, period)
    reads = [slow, *[fast] * (MODEL.p - 1)]
    cov = coverage(reads, frames, window, MODEL.min_sensors)
    line = cov.refusal(MODEL.ids())
    share = cov.link_share[0]
    if window > period * 1.05:
        assert share > 0.95 and line is None
    if window < 0.45 * period:
        assert share < 0.5
    if share < aligned.MIN_LINK_SHARE:
        assert line is not None and line.count("\n") == 0
        assert f"10: {cov.per_second[0]:.2f}/s in {share:.0%}" in line and "11:" not in line
        assert f"asynchronous window {window:g} s at {cov.rate_hz:.3g} Hz" in line
    else:
        assert line is None


def test_a_recording_without_enough_links_is_refused_whatever_the_links() -> None:
    frames = np.arange(1.0, 30.0, 0.5)
    reads = [np.arange(0.0, 30.0, 0.1), np.arange(0.0, 30.0, 0.1)] + [np.zeros(0)] * (MODEL.p - 2)
    line = coverage(reads, frames, 0.5, MODEL.min_sensors).refusal(MODEL.ids())
    assert line is not None and "only 0% of the outputs hold the 3 readings a fix needs" in line


def test_a_window_must_be_positive() -> None:
    with pytest.raises(ValueError, match="async_window_s=0"):
        aligned.create("ls", MODEL, async_window_s=0.0)

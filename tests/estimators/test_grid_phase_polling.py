"""Readings polled on the output grid (issue 34, item 1; estimators.aligned.default_window): a tag that reads all its
anchors one after another at the start of every output period, as the Hanyang outdoor UWB recordings do. A window of
exactly one period then leaves the link read first in the previous cycle out of many outputs (its reading is one
period old to the last bit); the default window covers the slowest link's reading interval instead, and the
asynchronous least squares and EKF are then no worse than framing."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import aligned
from estimators.registry import create
from estimators.scenario_models import anchor_model
from secuav_common.scenario import load_scenario

MODEL = anchor_model(load_scenario("anchors8"), dims=2)
HEIGHT = -2.5
PERIOD = 0.1


def _grid_polled(seconds: float, speed: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every period a poll cycle starting exactly on the output grid: the first link at k * PERIOD, the others 1 ms
    apart after it, in an order that rotates. Returns reading times, readings (N, p), output times, true positions
    at the output times."""
    rng = np.random.default_rng(seed)
    w = speed / 1.5
    out = np.arange(1, int(seconds / PERIOD)) * PERIOD

    def at(t: np.ndarray) -> np.ndarray:
        return np.column_stack([2.5 + 1.5 * np.cos(w * t), 2.5 + 1.5 * np.sin(w * t)])

    times, rows = [], []
    for k in range(int(seconds / PERIOD)):
        order = np.roll(np.arange(MODEL.p), -(k % MODEL.p))
        for j, link in enumerate(order):
            t = k * PERIOD + j * 0.001  # j = 0: exactly on the grid, the same float as the output time
            z = np.full(MODEL.p, np.nan)
            z[link] = MODEL.h(at(np.array([t]))[0], HEIGHT)[link] + rng.normal(0.0, 0.05)
            times.append(t)
            rows.append(z)
    return np.array(times), np.array(rows), out, at(out)


def _framed(name: str, t: np.ndarray, z: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Frame k holds each link's last reading in (t_{k-1}, t_k], NaN if none, taken as simultaneous."""
    est = create(name, MODEL)
    pos, prev = [], -np.inf
    for tk in out:
        frame = np.full(MODEL.p, np.nan)
        for j in np.flatnonzero((t > prev) & (t <= tk)):
            frame = np.where(np.isfinite(z[j]), z[j], frame)
        pos.append(est.step(float(tk), frame, HEIGHT).position_m[:2])
        prev = tk
    return np.array(pos)


def _asynchronous(name: str, t: np.ndarray, z: np.ndarray, out: np.ndarray, window: float) -> np.ndarray:
    est = aligned.create(name, MODEL, async_window_s=window)
    pos, j = [], 0
    for tk in out:
        while j < t.size and t[j] <= tk:
            est.read(float(t[j]), z[j], HEIGHT)
            j += 1
        pos.append(est.step(float(tk), None, HEIGHT).position_m[:2])
    return np.array(pos)


def _rmse(pos: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((pos[10:] - truth[10:]) ** 2, axis=1))))


def _read_times(t: np.ndarray, z: np.ndarray) -> list[np.ndarray]:
    return [t[np.isfinite(z[:, i])] for i in range(MODEL.p)]


def test_one_period_leaves_a_link_out_and_the_default_covers_every_link() -> None:
    t, z, out, _ = _grid_polled(20.0, 1.0, seed=1)
    period = float(np.median(np.diff(out)))  # one output period, as the old default took it
    old = aligned.coverage(_read_times(t, z), out, period, MODEL.min_sensors)
    window = aligned.default_window(out, _read_times(t, z))
    new = aligned.coverage(_read_times(t, z), out, window, MODEL.min_sensors)
    assert PERIOD < window < 1.1 * PERIOD  # the slowest link's reading interval, a little over the period
    assert min(old.link_share) < 0.95  # a period to the last bit: the link read first a cycle ago is often out
    assert min(new.link_share) == 1.0 and new.refusal(MODEL.ids()) is None


@pytest.mark.parametrize("name", ["ls", "ekf"])
@pytest.mark.parametrize(("speed", "seed"), [(0.3, 2), (1.0, 3), (2.0, 4)])
def test_asynchronous_is_no_worse_than_framed_on_grid_polling(name: str, speed: float, seed: int) -> None:
    """The undefended baselines, which every secure method is compared with, do not lose by taking the readings
    at their own times: with the default window no worse than framed (which takes a cycle's readings as
    simultaneous), at walking to running speed."""
    t, z, out, truth = _grid_polled(20.0, speed, seed)
    window = aligned.default_window(out, _read_times(t, z))
    framed = _rmse(_framed(name, t, z, out), truth)
    got = _rmse(_asynchronous(name, t, z, out, window), truth)
    assert got <= framed, (name, speed, got, framed)


def test_a_restart_searches_from_the_last_valid_position() -> None:
    """After the envelope restarts an estimator (a step beyond the motion bound), its next cold fix starts at the
    last position claimed valid, not amid the anchors (where a far tag's mirror image can win the search)."""
    est = create("ls", MODEL)
    here = np.array([2.0, 3.0])
    first = est.step(0.0, MODEL.h(here, HEIGHT), HEIGHT)
    assert first.valid and est.restart_pos is None
    jumped = est.step(0.1, MODEL.h(here + np.array([4.0, 0.0]), HEIGHT), HEIGHT)  # 4 m in 0.1 s: beyond the bound
    assert jumped.reinitialised and not jumped.valid
    assert np.allclose(est.restart_pos, first.position_m)
    again = est.step(1.0, MODEL.h(here + np.array([4.0, 0.0]), HEIGHT), HEIGHT)
    assert again.valid and np.allclose(again.position_m[:2], here + np.array([4.0, 0.0]), atol=1e-6)

"""Exact values over time for the value primitives: bias, ramp, set, scale, sinusoid, drop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from attack_profiles import FORWARD
from tests.support.attack_helpers import attacked_cm, distance, make_profile, rule, send, started


def test_bias_adds_offset_in_metres_inside_window_only() -> None:
    engine = started(make_profile(rule("bias", offset=1.25, start_s=2, end_s=4)))
    assert [attacked_cm(engine, t, 0, 250) for t in (0.0, 1.99, 2.0, 3.99, 4.0)] == [250, 250, 375, 375, 250]


def test_bias_accepts_design_spelling_offset_m() -> None:
    engine = started(make_profile(rule("bias", offset_m=-0.5)))
    assert attacked_cm(engine, 0.0, 0, 250) == 200


def test_ramp_grows_from_window_start() -> None:
    engine = started(make_profile(rule("ramp", rate_per_s=0.2, start_s=10, end_s=40)))
    got = [attacked_cm(engine, t, 0, 250) for t in (5.0, 10.0, 15.0, 39.0, 40.0)]
    assert got == [250, 250, 350, 250 + round(0.2 * 29 * 100), 250]


def test_ramp_restarts_each_repeat() -> None:
    engine = started(make_profile(rule("ramp", rate_per_s=1.0, start_s=1, end_s=3, repeat_period_s=5)))
    got = [attacked_cm(engine, t, 0, 100) for t in (1.5, 2.5, 3.5, 6.5, 7.5, 8.5)]
    assert got == [150, 250, 100, 150, 250, 100]


def test_set_replaces_value_and_leaves_other_sensors() -> None:
    engine = started(make_profile(rule("set", sensor_id=[1, 2], value=0.0)))
    assert attacked_cm(engine, 0.0, 1, 250) == 0
    assert attacked_cm(engine, 0.0, 2, 250) == 0
    assert send(engine, 0.0, distance(3, 250)) == FORWARD


def test_scale_multiplies() -> None:
    engine = started(make_profile(rule("scale", factor=1.5)))
    assert attacked_cm(engine, 0.0, 0, 200) == 300


def test_sinusoid_exact_values() -> None:
    engine = started(make_profile(rule("sinusoid", amplitude=0.5, period_s=4.0, phase_deg=90.0)))
    for t in (0.0, 1.0, 2.0, 3.0, 0.5):
        expected = round((2.0 + 0.5 * math.sin(2 * math.pi * t / 4.0 + math.pi / 2)) * 100)
        assert attacked_cm(engine, t, 0, 200) == expected


def test_drop_all_and_only_in_window() -> None:
    engine = started(make_profile(rule("drop", start_s=1, end_s=2)))
    assert send(engine, 0.5, distance(0, 100)) == FORWARD
    action = send(engine, 1.5, distance(0, 100))
    assert action.drop and action.rules == (0,)
    assert not send(engine, 2.5, distance(0, 100)).drop


def test_drop_probability_is_roughly_respected_and_seeded() -> None:
    def pattern(seed: int) -> list[bool]:
        engine = started(make_profile(rule("drop", probability=0.3)), seed=seed)
        return [send(engine, i * 0.01, distance(0, 100)).drop for i in range(2000)]

    first = pattern(1)
    assert first == pattern(1)
    assert first != pattern(2)
    assert 0.25 < sum(first) / len(first) < 0.35


def test_apply_array_bias_ramp_drop_in_metres() -> None:
    profile = make_profile(
        rule("bias", sensor_id=12, offset=2.0),
        rule("ramp", sensor_id=0, rate_per_s=0.5, start_s=1, end_s=3),
        rule("drop", sensor_id=0, start_s=3, end_s=4),
    )
    engine = started(profile)
    t = np.arange(0.0, 5.0, 1.0)
    z = np.column_stack([np.full(5, 2.5), np.full(5, 4.0), np.full(5, 1.0)])
    z[4, 2] = np.nan
    out = engine.apply_array(t, z, [0, 12, 7])
    np.testing.assert_allclose(out[:, 0], [2.5, 2.5, 3.0, np.nan, 2.5])
    np.testing.assert_allclose(out[:, 1], [6.0] * 5)
    np.testing.assert_allclose(out[:, 2], [1.0, 1.0, 1.0, 1.0, np.nan])
    assert np.isnan(z[4, 2]) and z[0, 1] == 4.0  # input untouched


def test_apply_array_is_repeatable_and_independent_of_live_state() -> None:
    engine = started(make_profile(rule("noise", std=0.1)), seed=5)
    t = np.linspace(0, 1, 50)
    z = np.ones((50, 1))
    first = engine.apply_array(t, z, [0])
    attacked_cm(engine, 0.0, 0, 100)  # live use in between must not shift the offline stream
    np.testing.assert_array_equal(first, engine.apply_array(t, z, [0]))


def test_apply_array_rejects_bad_shapes() -> None:
    engine = started(make_profile(rule("bias", offset=1.0)))
    with pytest.raises(ValueError, match="sensor ids"):
        engine.apply_array(np.zeros(3), np.zeros((3, 2)), [0])
    with pytest.raises(ValueError, match="must not decrease"):
        engine.apply_array(np.array([0.0, 2.0, 1.0]), np.zeros((3, 1)), [0])

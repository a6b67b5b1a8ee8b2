"""The example plugin's own tests: its estimator and its primitive as SecUAV's libraries run them."""

from __future__ import annotations

import numpy as np
import pytest
from secuav_example_plugin.huber import Huber
from secuav_example_plugin.moving_bias import MovingBias

from attack_profiles import Engine, parse_profile
from estimators import AnchorRanges2D, create, known

ANCHORS = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0], [2.0, 0.0], [0.0, 2.0]])


def _model() -> AnchorRanges2D:
    return AnchorRanges2D.build(np.column_stack([ANCHORS, np.full(6, -1.0)]), 0.1, -2.0)


def _ranges(pos: np.ndarray, model: AnchorRanges2D) -> np.ndarray:
    return model.h(pos, model.default_known)


def test_secuav_finds_the_estimator_by_its_entry_point_name() -> None:
    assert known("huber") and isinstance(create("huber", _model()), Huber)


def test_one_large_lie_moves_huber_far_less_than_least_squares() -> None:
    model, truth = _model(), np.array([2.0, 2.0])
    z = _ranges(truth, model)
    z[0] += 3.0  # one anchor reads 3 m long
    errors = {}
    for name in ("ls", "huber"):
        est = create(name, model)
        for k in range(10):
            out = est.step(0.1 * k, z)
        errors[name] = float(np.linalg.norm(out.position_m - truth))
    assert errors["huber"] < 0.5 * errors["ls"], errors


def test_huber_k_out_of_its_range_is_refused() -> None:
    with pytest.raises(ValueError, match="huber_k"):
        create("huber", _model(), huber_k=50.0)


PROFILE = """
name: mb
rules:
  - kind: moving_bias
    target: {message: DISTANCE_SENSOR, sensor_id: 10}
    offset: 1.5
    min_speed_mps: 0.3
"""


def test_the_bias_acts_only_while_the_vehicle_moves() -> None:
    profile = parse_profile(PROFILE, "mb.yaml")
    assert type(profile.rules[0]).__name__ == "MovingBiasRule"
    t = np.arange(0.0, 6.0, 0.1)
    north = np.where(t < 2.0, 0.0, np.where(t < 4.0, (t - 2.0) * 1.0, 2.0))  # still, 1 m/s for 2 s, still
    position = np.column_stack([north, np.zeros_like(t), np.full_like(t, -2.0)])
    z = np.full((t.size, 1), 5.0)
    out = Engine(profile).apply_array(t, z, [10], position_ned_m=position)
    added = out[:, 0] - 5.0
    # Over the last 0.5 s the speed passes 0.3 m/s 0.15 s after the start and falls below it 0.35 s after the stop.
    assert np.allclose(added[(t > 2.25) & (t < 4.25)], 1.5)
    assert np.allclose(added[t < 2.1], 0.0) and np.allclose(added[t > 4.45], 0.0)


def test_the_primitive_is_registered_under_its_kind() -> None:
    from attack_profiles.primitives import primitive

    assert primitive("moving_bias") is MovingBias


def test_huber_names_the_liar_itself_through_the_public_contract() -> None:
    """Its own claim (detects = True): the reading 3 m long is named, an alarm raised, the answer still valid
    (five honest readings pin the position down); the base class records it as the method's own."""
    model, truth = _model(), np.array([2.0, 2.0])
    z = _ranges(truth, model)
    z[0] += 3.0
    est = create("huber", model)
    for k in range(10):
        out = est.step(0.1 * k, z)
    assert out.attacked == frozenset({0}) and out.alarm and out.valid
    assert out.own_attacked == frozenset({0}) and out.own_alarm
    assert 0 not in out.used

"""The motion input: the filters read the vehicle's own velocity (issue 26)."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from estimators.bank import EkfBank
from estimators.models import AnchorRanges2D
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M


def test_the_velocity_update_is_the_textbook_kalman_update() -> None:
    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    bank = EkfBank(model, np.ones((3, 8), dtype=bool), 0.5)
    rng = np.random.default_rng(2)
    for j in range(3):
        a = rng.standard_normal((4, 4))
        bank.seed(rng.standard_normal(4), a @ a.T + np.eye(4), np.array([j]))
    x0, p0 = bank.x.copy(), bank.P.copy()
    vel, var = np.array([0.3, -0.2]), 0.01
    bank.update_velocity(vel, var)
    h = np.hstack([np.zeros((2, 2)), np.eye(2)])
    for j in range(3):
        gain = p0[j] @ h.T @ np.linalg.inv(h @ p0[j] @ h.T + var * np.eye(2))
        np.testing.assert_allclose(bank.x[j], x0[j] + gain @ (vel - h @ x0[j]), atol=1e-10)
        np.testing.assert_allclose(bank.P[j], (np.eye(4) - gain @ h) @ p0[j], atol=1e-10)


def test_only_filters_take_a_motion_input() -> None:
    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    assert estimators.create("secekf", model, velocity_std_mps=0.1).velocity_std_mps == 0.1
    with pytest.raises(ValueError, match="secopt has no motion input"):
        estimators.create("secopt", model, velocity_std_mps=0.1)
    with pytest.raises(ValueError, match="positive"):
        estimators.create("ekf", model, velocity_std_mps=0.0)


def _ramp(velocity_std: float | None, seed: int) -> tuple[float, float]:
    """Three links ramp at 0.02 m/s from 5 s while the vehicle flies a slow circle; the filter is told the
    vehicle's velocity (truth + 0.05 m/s noise) or not. (worst error claimed valid, RMSE)."""
    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    est = estimators.create("secekf", model, velocity_std_mps=velocity_std)
    rng = np.random.default_rng(seed)
    worst, sq = 0.0, []
    for k in range(600):
        t = 0.1 * k
        truth = np.array([2.5 + np.cos(0.1 * t), 2.5 + np.sin(0.1 * t)])
        vel = 0.1 * np.array([-np.sin(0.1 * t), np.cos(0.1 * t), 0.0]) + 0.05 * rng.standard_normal(3)
        z = model.h(truth) + SIGMA_M * rng.standard_normal(8)
        if t >= 5.0:
            z[[1, 4, 6]] += 0.02 * (t - 5.0)
        out = est.step(t, z, velocity=vel)
        err = float(np.linalg.norm(out.position_m - truth))
        sq.append(err * err)
        if out.valid:
            worst = max(worst, err)
    return worst, float(np.sqrt(np.mean(sq)))


def test_the_vehicles_motion_holds_the_filter_against_a_slow_three_link_ramp() -> None:
    """Beyond tolerance and slow: without the motion input the filter follows the ramp (it reads as a velocity
    the vehicle does not have); told the vehicle's own velocity it cannot, the ramped links stand out."""
    for seed in range(3):
        plain, told = _ramp(None, seed), _ramp(0.1, seed)
        assert told[1] < plain[1], (seed, plain, told)


def test_a_wall_group_moves_at_the_velocity_along_its_normal() -> None:
    """The distance to a wall changes at the velocity along the wall's normal; a group without one has no
    motion input rather than a wrong one."""
    from estimators.models import ScalarGroup

    toward_north_wall = ScalarGroup.build([0.02] * 5, normal_ned=(-2.0, 0.0, 0.0))
    assert toward_north_wall.normal_ned == (-1.0, 0.0, 0.0)
    np.testing.assert_allclose(toward_north_wall.state_velocity(np.array([0.8, 0.3, -0.1])), [-0.8])
    diagonal = ScalarGroup.build([0.02] * 3, normal_ned=(1.0, 1.0, 0.0))
    np.testing.assert_allclose(diagonal.state_velocity(np.array([1.0, 0.0, 0.0])), [np.sqrt(0.5)])
    assert ScalarGroup.build([0.02] * 3).state_velocity(np.array([1.0, 0.0, 0.0])) is None
    assert toward_north_wall.state_velocity(np.array([np.nan, 0.0, 0.0])) is None
    with pytest.raises(ValueError, match="normal_ned"):
        ScalarGroup.build([0.02] * 3, normal_ned=(0.0, 0.0, 0.0))

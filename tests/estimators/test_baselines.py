"""ls and ekf: accurate without attack, NaN-tolerant, and (being undefended) dragged by an attack."""

from __future__ import annotations

import numpy as np

import estimators
from estimators.models import AnchorRanges2D, AnchorRanges3D, ScalarGroup
from tests.support.est_helpers import ANCHORS8_NED_M, HOVER_XY_M, SIGMA_M


def _run(name: str, model, truth: np.ndarray, steps: int, bias: np.ndarray | None = None, seed: int = 0):
    rng = np.random.default_rng(seed)
    est = estimators.create(name, model)
    errs = []
    for k in range(steps):
        z = model.h(truth) + model.sigma_m * rng.standard_normal(model.p)
        if bias is not None and k >= steps // 2:
            z = z + bias
        out = est.step(0.1 * k, z)
        errs.append(np.linalg.norm(out.position_m - truth))
    return np.array(errs), out


def test_names_and_unknown_name(anchors8: AnchorRanges2D) -> None:
    assert {"ls", "ekf"} <= set(estimators.names())
    try:
        estimators.create("nope", anchors8)
    except ValueError as err:
        assert "nope" in str(err)
    else:
        raise AssertionError("unknown name accepted")


def test_clean_accuracy_at_noise_level(anchors8: AnchorRanges2D) -> None:
    for name in ("ls", "ekf"):
        errs, out = _run(name, anchors8, HOVER_XY_M, 60)
        assert np.sqrt(np.mean(errs**2)) < 2 * SIGMA_M, name
        assert out.attacked == frozenset() and not out.alarm and out.step_time_s > 0


def test_ekf_carries_velocity_and_covariance(anchors8: AnchorRanges2D) -> None:
    _, out = _run("ekf", anchors8, HOVER_XY_M, 30)
    assert out.velocity_mps is not None and out.velocity_mps.shape == (2,)
    assert out.covariance is not None and out.covariance.shape == (4, 4)


def test_undefended_baselines_are_dragged(anchors8: AnchorRanges2D) -> None:
    bias = np.zeros(8)
    bias[[2, 3]] = 3.0
    for name in ("ls", "ekf"):
        errs, _ = _run(name, anchors8, HOVER_XY_M, 80, bias)
        assert np.median(errs[-20:]) > 5 * np.median(errs[:40]), name


def test_nan_readings_are_left_out(anchors8: AnchorRanges2D) -> None:
    rng = np.random.default_rng(1)
    for name in ("ls", "ekf"):
        est = estimators.create(name, anchors8)
        for k in range(40):
            z = anchors8.h(HOVER_XY_M) + SIGMA_M * rng.standard_normal(8)
            z[rng.choice(8, size=3, replace=False)] = np.nan
            out = est.step(0.1 * k, z)
            assert len(out.used) == 5
        assert np.linalg.norm(out.position_m - HOVER_XY_M) < 4 * SIGMA_M, name


def test_scalar_group_and_3d(wall_group: ScalarGroup) -> None:
    rng = np.random.default_rng(2)
    for name in ("ls", "ekf"):
        errs, _ = _run(name, wall_group, np.array([2.5]), 40, seed=3)
        assert np.max(errs) < 0.1, name
    model3 = AnchorRanges3D.build(ANCHORS8_NED_M + np.array([0, 0, 0]) * rng.random(), SIGMA_M)
    errs, _ = _run("ls", model3, np.array([2.0, 3.0, -2.5]), 30)
    assert np.sqrt(np.mean(errs**2)) < 0.5

"""The process noise fitted on the calibration window instead of guessed (issue 34, item 2; estimators.motion), and
what results.json says about it (``calibration.process_noise``)."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import noise
from estimators.bank import cv_matrices
from estimators.models import AnchorRanges2D
from estimators.motion import GRID_MPS2, fit_process_noise

# Eight anchors on a 200 m square (corners and midpoints): room for a random walk of 3 m/s^2 for 30 s, so the
# motion is the constant-velocity model's own (a vehicle turned back at the edge of a 5 m room is not).
_SIDE = [0.0, 100.0, 200.0]
ANCHORS = [[n, e, 0.0] for n in _SIDE for e in _SIDE if (n, e) != (100.0, 100.0)]
MODEL = AnchorRanges2D.build(ANCHORS, sigma_m=0.05, sensor_ids=tuple(range(10, 18)))
HEIGHT = -2.5
DT = 0.1


def _flight(q_mps2: float, steps: int, sigma: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The constant-velocity model itself with white acceleration of std q (the estimators' convention), from the
    square's centre; ranges with Gaussian noise."""
    rng = np.random.default_rng(seed)
    f, _ = cv_matrices(2, DT, q_mps2)
    g = np.vstack([0.5 * DT**2 * np.eye(2), DT * np.eye(2)])
    x = np.array([100.0, 100.0, 0.0, 0.0])
    t = np.arange(steps) * DT
    pos, z = np.zeros((steps, 2)), np.zeros((steps, MODEL.p))
    for k in range(steps):
        x = f @ x + g @ (q_mps2 * rng.standard_normal(2))
        pos[k] = x[:2]
        z[k] = MODEL.h(x[:2], HEIGHT) + rng.normal(0.0, sigma, MODEL.p)
    return t, z, pos


@pytest.mark.parametrize("q_true", [0.3, 1.0, 3.0])
def test_the_fit_finds_the_motions_process_noise(q_true: float) -> None:
    t, z, _ = _flight(q_true, 300, 0.05, seed=int(q_true * 10))
    fit = fit_process_noise(MODEL, t, z, [HEIGHT] * t.size)
    assert fit is not None and fit.fixes == 300 and fit.at_bound is None
    assert q_true / 2 <= fit.q_mps2 <= 2 * q_true
    assert fit.report() == {"q_mps2": round(fit.q_mps2, 4), "source": "fitted", "fixes": 300, "at_bound": None}


def test_a_parked_vehicle_fits_the_floor_and_says_so() -> None:
    t, z, _ = _flight(0.0, 200, 0.05, seed=1)
    fit = fit_process_noise(MODEL, t, z, [HEIGHT] * t.size)
    assert fit is not None and fit.q_mps2 <= 0.05
    assert fit.at_bound == "low" or fit.q_mps2 > GRID_MPS2[0]


def test_too_few_fixes_fit_nothing() -> None:
    t, z, _ = _flight(1.0, 30, 0.05, seed=2)
    z[:, 3:] = np.nan  # three links: a fix at every step but two of them
    z[2:, 2] = np.nan
    assert fit_process_noise(MODEL, t, z, [HEIGHT] * t.size) is None


def _calibrated(seconds: float = 30.0, **params: float) -> noise.Calibrated:
    t, z, _ = _flight(1.0, int(seconds / DT), 0.05, seed=4)
    est = noise.create("secekf", MODEL, calibration_s=20.0, **params)
    assert isinstance(est, noise.Calibrated)
    for k in range(t.size):
        est.step(float(t[k]), z[k], HEIGHT, velocity=np.array([0.0, 0.0, 0.0]))
    return est


def test_the_calibrated_estimator_runs_with_the_fitted_value_and_says_so() -> None:
    est = _calibrated()
    rep = est.report()["process_noise"]
    assert rep["source"] == "fitted" and 0.5 <= rep["q_mps2"] <= 2.0
    assert est.core.q_mps2 == pytest.approx(rep["q_mps2"], abs=1e-4)
    assert est.process_noise is not None and est.process_noise.fixes == 201


def test_a_given_value_or_the_vehicles_motion_is_not_overridden() -> None:
    given = _calibrated(q_mps2=0.7)
    assert given.report()["process_noise"] == {"q_mps2": 0.7, "source": "given"}
    assert given.core.q_mps2 == 0.7
    moving = _calibrated(velocity_std_mps=0.1)
    assert moving.report()["process_noise"] == {"q_mps2": 0.5, "source": "motion input"}

"""Seed test case 1 geometry and a synthetic stream runner shared by the estimator tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

import estimators
from estimators.models import MeasurementModel

ANCHORS8_NED_M = np.array(
    [
        [0.0, 0.0, -1.0],
        [2.5, 0.0, -1.0],
        [5.0, 0.0, -1.0],
        [5.0, 2.5, -1.0],
        [5.0, 5.0, -1.0],
        [2.5, 5.0, -1.0],
        [0.0, 5.0, -1.0],
        [0.0, 2.5, -1.0],
    ]
)
HOVER_XY_M = np.array([2.5, 2.5])
SIGMA_M = 0.1
SECURE = ("l1", "secekf", "secopt", "recap", "rarse")

# attack(k, z_clean) -> additive offset per sensor (0 = honest)
Attack = Callable[[int, np.ndarray], np.ndarray]


@dataclass
class Run:
    err_m: np.ndarray  # per step, position error
    alarm: np.ndarray  # per step
    attacked: list[frozenset[int]]
    offsets: np.ndarray  # (steps, p) what the attacker added
    used: list[frozenset[int]]  # per step, the readings the estimate rests on


def run_stream(
    name: str, model: MeasurementModel, truth: np.ndarray, attack: Attack, steps: int, seed: int, **params
) -> Run:
    """Hover at ``truth``, 10 Hz, Gaussian noise of the model's std, plus the attack's offsets."""
    rng = np.random.default_rng(seed)
    est = estimators.create(name, model, **params)
    clean = model.h(truth)
    errs, alarms, attacked, offsets, used = [], [], [], [], []
    for k in range(steps):
        z = clean + model.sigma_m * rng.standard_normal(model.p)
        off = attack(k, z)
        out = est.step(0.1 * k, z + off)
        errs.append(float(np.linalg.norm(out.position_m - truth)))
        alarms.append(out.alarm)
        attacked.append(out.attacked)
        offsets.append(off)
        used.append(frozenset(out.used))
    return Run(np.array(errs), np.array(alarms), attacked, np.array(offsets), used)

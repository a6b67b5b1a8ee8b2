"""The attacker who knows the defence (evaluation/adaptive.py): never caught, and it does damage."""

from __future__ import annotations

import numpy as np

from estimators.models import AnchorRanges2D
from evaluation.adaptive import attack
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M


def _hover(n: int, seed: int) -> tuple[AnchorRanges2D, np.ndarray, np.ndarray, np.ndarray]:
    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    rng = np.random.default_rng(seed)
    truth = np.tile([2.5, 2.5], (n, 1))
    z = model.h(truth) + SIGMA_M * rng.standard_normal((n, 8))
    return model, 0.1 * np.arange(n), z, truth


def test_no_committed_step_is_caught_and_the_estimate_is_moved() -> None:
    """Three adjacent links against SecEKF: every step the attacker commits is claimed valid with none of its
    links named (it probes a copy first), and still the estimate is pulled well beyond the noise."""
    model, t, z, truth = _hover(150, 3)
    seen = np.column_stack([truth, np.full(len(t), -2.5)])
    run = attack(model, "secekf", t, z, truth, seen, [1, 2, 3], 135.0, start_s=2.0)
    attacked = run.delta_m > 0
    assert attacked.sum() > 50
    assert run.valid[attacked].all()
    assert run.damage_m > 3 * SIGMA_M, run.damage_m
    assert np.nanmax(run.err_m[~attacked & (t < 2.0)]) < 3 * SIGMA_M  # before the onset: the clean estimate

"""Evidence against a subset builds up over time (``subsets.Evidence``): a bias too small for any one window
still loses the subset bank's ranking, and the ranking follows an attack that moves to other sensors."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.models import AnchorRanges2D
from estimators.subsets import Evidence
from tests.support.est_helpers import HOVER_XY_M, SIGMA_M, run_stream

STEPS = 400  # 40 s at 10 Hz


def test_evidence_stays_near_zero_on_clean_statistics_and_climbs_to_the_cap_on_biased_ones() -> None:
    rng = np.random.default_rng(0)
    ev = Evidence(2)
    dof = np.array([6, 6])
    peak_clean = 0.0
    shift = np.array([2.0, 2.0, 0.0, 0.0, 0.0, 0.0])  # two of the six readings 2 sigma off
    for _ in range(2000):
        clean = rng.chisquare(6)
        biased = float(np.sum((rng.standard_normal(6) + shift) ** 2))
        g = ev.update(np.array([clean, biased]), dof)
        peak_clean = max(peak_clean, g[0])
    assert g[1] == ev.limit and peak_clean < ev.limit
    for _ in range(3):  # the bias stops: the evidence drains, but only at the drift rate
        g = ev.update(np.array([6.0, 6.0]), dof)
    assert g[1] == pytest.approx(ev.limit - 3 * ev.drift)


def test_no_readings_only_drain() -> None:
    ev = Evidence(1)
    ev.g[:] = 4.0
    assert ev.update(np.array([1e9]), np.array([0]))[0] == pytest.approx(4.0 - ev.drift)


@pytest.mark.parametrize("name", ["secekf", "secopt"])
def test_a_two_sigma_bias_is_left_out_on_most_steps(name: str, anchors8: AnchorRanges2D) -> None:
    # Links 1 and 4 read 2 sigma long: every window test passes with them in, so only accumulated evidence tells.
    bias = np.zeros(anchors8.p)
    bias[[1, 4]] = 2.0 * SIGMA_M
    left_out = []
    for seed in range(3):
        run = run_stream(name, anchors8, HOVER_XY_M, lambda k, z: bias, STEPS, seed)
        left_out += [not ({1, 4} & run.used[k]) for k in range(100, STEPS)]
    # Measured over these seeds: 0.95 (secekf) and 0.96 (secopt) with evidence, 0.59 and 0.64 with the window
    # ranking alone (Evidence with limit 0); RMSE 0.05-0.06 m against 0.06-0.08 m.
    assert np.mean(left_out) > 0.8

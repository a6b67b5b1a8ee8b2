"""milp.py tells a solver timeout apart from a proof that more than s readings lie (issue 26)."""

from __future__ import annotations

import numpy as np

import estimators
from estimators.models import AnchorRanges2D
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M


def _perimeter(p: int) -> np.ndarray:
    t = np.arange(p) / p * 4.0
    side, frac = np.floor(t), t - np.floor(t)
    corners = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.0]])
    xy = corners[side.astype(int)] + frac[:, None] * (corners[side.astype(int) + 1] - corners[side.astype(int)])
    return np.column_stack([xy, np.full(p, -1.0)])


def test_a_timeout_is_not_an_alarm() -> None:
    """p = 24, s = 4, a time limit far too short for HiGHS to prove anything: before, every such solve was taken
    as "more than s attacked" (an alarm on clean readings); now it is counted as a timeout, marked not valid, and
    raises no alarm."""
    model = AnchorRanges2D.build(_perimeter(24), SIGMA_M)
    est = estimators.create("milp", model, s=4, time_limit_s=1e-6)
    rng = np.random.default_rng(0)
    truth = np.array([4.0, 6.0])
    outs = [est.step(0.1 * k, model.h(truth) + SIGMA_M * rng.standard_normal(24)) for k in range(5)]
    counts = est.status_counts
    assert counts["timeout_none"] + counts["timeout_incumbent"] >= 1, counts
    assert counts["infeasible"] == 0, counts
    assert not any(o.alarm for o in outs), [o.alarm for o in outs]
    # A timeout with no incumbent gives no estimate to trust: exactly those steps are not valid.
    assert sum(not o.valid for o in outs) == counts["timeout_none"], (counts, [o.valid for o in outs])


def test_infeasible_is_still_an_alarm() -> None:
    """Three links 2 m off with s = 1 on the seed's layout: HiGHS proves no single liar explains them."""
    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    est = estimators.create("milp", model, s=1)
    rng = np.random.default_rng(1)
    truth = np.array([2.5, 2.5])
    alarms = []
    for k in range(6):
        z = model.h(truth) + SIGMA_M * rng.standard_normal(8)
        z[[0, 3, 5]] += 2.0
        alarms.append(est.step(0.1 * k, z).alarm)
    assert est.status_counts["infeasible"] >= 5 and all(alarms[1:]), (est.status_counts, alarms)

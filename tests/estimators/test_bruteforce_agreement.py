"""Each secure estimator agrees with an independent brute force over all sensor subsets.

The brute force uses scipy.optimize.least_squares on every subset of p - s
readings (no code shared with the estimators' bank), keeps the subsets whose
weighted cost passes chi2.ppf(0.99, n - d), and takes the cheapest of those with
the most readings. Its verdicts: alarm when none passes; attacked = readings
outside the winner whose residual against its fit exceeds the chi2_1 gate.
Attacks are large (>= 1 m, 10 sigma) so the verdict is unambiguous and
estimators, whatever their route, must land on it on the first step.
"""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.stats import chi2

import estimators
from estimators.models import AnchorRanges2D, ScalarGroup
from tests.support.est_helpers import ANCHORS8_NED_M, SECURE

ALPHA = 0.01


def brute_force(model, z: np.ndarray, s: int, start: np.ndarray):
    """(alarm, position, attacked set) by exhaustive search, see module docstring."""
    avail = [i for i in range(model.p) if not np.isnan(z[i])]
    best = None
    for keep in itertools.combinations(avail, max(len(avail) - s, 0)):
        idx = list(keep)
        if len(idx) < model.min_sensors:
            continue

        def resid(pos, idx=idx):
            return (z[idx] - model.h(pos)[idx]) / model.sigma_m[idx]

        fit = least_squares(resid, start, method="lm" if len(idx) >= model.d else "trf")
        cost = float(np.sum(fit.fun**2))
        dof = len(idx) - model.d
        if dof > 0 and cost > chi2.ppf(1 - ALPHA, dof):
            continue
        if best is None or cost < best[0]:
            best = (cost, fit.x, idx)
    if best is None:
        return True, None, None
    _, pos, idx = best
    r = (z - model.h(pos)) / model.sigma_m
    attacked = {i for i in avail if i not in idx and r[i] ** 2 > chi2.ppf(1 - ALPHA, 1)}
    return False, pos, attacked


CASES = settings(
    max_examples=40, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck), phases=[Phase.generate]
)


@CASES
@given(
    links=st.lists(st.integers(0, 7), min_size=0, max_size=3, unique=True),
    sizes=st.lists(st.floats(1.0, 50.0), min_size=3, max_size=3),
    signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=3, max_size=3),
    xy=st.tuples(st.floats(1.5, 3.5), st.floats(1.5, 3.5)),
    seed=st.integers(0, 2**16),
)
def test_anchor_snapshot_agrees(links, sizes, signs, xy, seed: int) -> None:
    model = AnchorRanges2D.build(ANCHORS8_NED_M, 0.1)
    truth = np.array(xy)
    rng = np.random.default_rng(seed)
    z = model.h(truth) + 0.1 * rng.standard_normal(8)
    for k, i in enumerate(links):
        z[i] = max(z[i] + signs[k] * sizes[k], 0.01)  # a range cannot be negative on the wire
    alarm, pos, attacked = brute_force(model, z, 2, model.initial_pos())
    for name in SECURE:
        out = estimators.create(name, model, s=2).step(0.0, z)
        assert out.alarm == alarm, (name, out.alarm, alarm)
        if not alarm:
            # Routes differ (6 or all honest readings, filter or fit): agree to noise level.
            assert np.linalg.norm(out.position_m - pos) < 0.2, name
            # A reading that noise alone put near the chi2_1 gate (|r| 2.58 against the fit; attacks
            # here are >= 10 sigma) may fall either side of it depending on which readings the fit
            # used: the routes need not agree on those, and must agree on every other reading.
            dev = np.abs(z - model.h(pos)) / 0.1
            borderline = {int(i) for i in np.flatnonzero((dev > 1.5) & (dev < 6.0))}
            assert set(out.attacked) ^ attacked <= borderline, (name, set(out.attacked), attacked)


@CASES
@given(
    links=st.lists(st.integers(0, 4), min_size=0, max_size=3, unique=True),
    values=st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3),
    seed=st.integers(0, 2**16),
)
def test_wall_group_agrees(links, values, seed: int) -> None:
    model = ScalarGroup.build([0.02, 0.02, 0.05, 0.04, 0.08])
    rng = np.random.default_rng(seed)
    z = 2.5 + model.sigma_m * rng.standard_normal(5)
    for k, i in enumerate(links):
        if abs(values[k] - 2.5) > 1.0:  # attacks of 1 m and more only (>= 12 sigma)
            z[i] = values[k]
    alarm, pos, attacked = brute_force(model, z, 2, np.array([2.5]))
    for name in SECURE:
        out = estimators.create(name, model, s=2).step(0.0, z)
        assert out.alarm == alarm, name
        if not alarm:
            assert abs(out.position_m[0] - pos[0]) < 0.05, name
            assert set(out.attacked) == attacked, name

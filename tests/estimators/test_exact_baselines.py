"""The exact and optimisation baselines: l0 (exhaustive), milp (Pajic's MILP on HiGHS), marzullo (interval fusion)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import estimators
from estimators.marzullo import fusion_interval
from estimators.models import AnchorRanges2D, ScalarGroup
from tests.support.est_helpers import HOVER_XY_M, SIGMA_M


def _stream(model: AnchorRanges2D, biased: list[int], offset_m: float, steps: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        z = model.h(HOVER_XY_M) + SIGMA_M * rng.standard_normal(model.p)
        z[biased] += offset_m
        out.append(z)
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_l0_and_milp_find_the_attacked_pair_and_agree(anchors8: AnchorRanges2D, seed: int) -> None:
    zs = _stream(anchors8, [1, 4], 1.5, 25, seed)
    l0, mi, sec = (estimators.create(n, anchors8) for n in ("l0", "milp", "secopt"))
    for k, z in enumerate(zs):
        a, b, c = l0.step(0.1 * k, z), mi.step(0.1 * k, z), sec.step(0.1 * k, z)
        assert not a.alarm and not b.alarm
        assert a.attacked == {1, 4} and b.attacked == {1, 4}, (k, a.attacked, b.attacked)
        assert np.linalg.norm(a.position_m - HOVER_XY_M) < 4 * SIGMA_M
        assert np.linalg.norm(a.position_m - b.position_m) < 2 * SIGMA_M  # same answer, two solvers
        if k >= 5:  # where secopt is right, the exact reference agrees with it
            assert np.linalg.norm(a.position_m - c.position_m) < 2 * SIGMA_M


def test_beyond_tolerance_the_exact_baselines_raise_the_alarm(anchors8: AnchorRanges2D) -> None:
    zs = _stream(anchors8, [0, 1, 2, 3], 1.5, 20, 3)  # four of eight: more than s = 2 can be corrected
    l0, mi = estimators.create("l0", anchors8), estimators.create("milp", anchors8)
    alarms = [(l0.step(0.1 * k, z).alarm, mi.step(0.1 * k, z).alarm) for k, z in enumerate(zs)]
    assert sum(a for a, _ in alarms) >= 18 and sum(b for _, b in alarms) >= 18


def test_l0_refuses_a_search_too_large_to_be_a_reference() -> None:
    ring = np.array([[10 * np.cos(a), 10 * np.sin(a), -1.0] for a in np.linspace(0, 2 * np.pi, 24, endpoint=False)])
    model = AnchorRanges2D.build(ring, SIGMA_M)
    assert "l0" not in estimators.names(model)
    with pytest.raises(ValueError, match="max_subsets"):
        estimators.create("l0", model)


def test_marzullo_fuses_the_wall_group_and_names_the_liars(wall_group: ScalarGroup) -> None:
    rng = np.random.default_rng(7)
    est = estimators.create("marzullo", wall_group)
    for k in range(40):
        z = 2.5 + wall_group.sigma_m * rng.standard_normal(5)
        z[[0, 1]] += 1.5  # both lasers lie together: two of five, the most it tolerates
        if k % 7 == 3:
            z[4] = np.nan  # a missing reading shrinks the group
        out = est.step(0.1 * k, z)
        if k % 7 != 3:  # with all five it names both; with four, two liars and two honest cannot be told apart
            assert not out.alarm and out.attacked == {0, 1}, (k, out)
        half_width = float(np.sqrt(out.covariance[0, 0] * est.gate1))
        assert abs(out.position_m[0] - 2.5) <= half_width + 1e-9  # the fused interval holds the truth


def test_marzullo_only_runs_on_one_measured_quantity(anchors8: AnchorRanges2D) -> None:
    with pytest.raises(ValueError, match="one quantity"):
        estimators.create("marzullo", anchors8)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-10, 10), st.floats(0.01, 5)), min_size=1, max_size=9), st.integers(1, 9))
def test_fusion_interval_holds_every_point_enough_intervals_cover(spans: list[tuple[float, float]], need: int) -> None:
    lo = np.array([c - w for c, w in spans])
    hi = np.array([c + w for c, w in spans])
    fused = fusion_interval(lo, hi, need)
    points = np.concatenate([lo, hi, np.linspace(-16, 16, 321)])
    covered = [x for x in points if ((lo <= x) & (x <= hi)).sum() >= need]
    if fused is None:
        assert not covered
        return
    a, b = fused
    assert covered and all(a - 1e-9 <= x <= b + 1e-9 for x in covered)
    for end in (a, b):  # the interval is the smallest such: its ends are covered
        assert ((lo <= end + 1e-9) & (end - 1e-9 <= hi)).sum() >= need


@pytest.mark.parametrize("name", ["secekf", "secopt", "recap", "rarse", "l1", "l0", "milp"])
def test_beyond_tolerance_no_estimator_claims_a_valid_estimate(anchors8: AnchorRanges2D, name: str) -> None:
    """Four of eight links biased 1.5 m after the estimators settled: degraded, never confidently wrong."""
    rng = np.random.default_rng(3)
    est = estimators.create(name, anchors8)
    claimed = []
    for k in range(60):
        z = anchors8.h(HOVER_XY_M) + SIGMA_M * rng.standard_normal(8)
        if k >= 20:
            z[[0, 1, 2, 3]] += 1.5
        out = est.step(0.1 * k, z)
        if k < 20:
            assert out.valid or k < 3, (k, out)
        elif k >= 25 and out.valid:
            claimed.append(np.linalg.norm(out.position_m - HOVER_XY_M))
    # Whatever is still claimed valid is no worse than the noise allows (the plain EKF is metres off here).
    assert all(e < 5 * SIGMA_M for e in claimed), claimed


def test_a_manoeuvre_that_surprises_the_filter_is_not_degraded(wall_group: ScalarGroup) -> None:
    """Two of five wall sensors ramp while the vehicle closes in at 1 m/s: within tolerance, so valid."""
    rng = np.random.default_rng(8)
    est = estimators.create("secekf", wall_group)
    for k in range(80):
        t = 0.1 * k
        truth = 5.0 - min(t, 2.5)  # 1 m/s toward the wall, then holding at 2.5 m
        z = truth + wall_group.sigma_m * rng.standard_normal(5)
        z[[0, 2]] += 0.4 * max(0.0, t - 1.0)
        out = est.step(t, z)
        assert out.valid, (k, out)

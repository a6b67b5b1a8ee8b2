"""``poly``, the polyhedral (set-membership) reading of RARSE: what it guarantees and where it is blind."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import estimators
from estimators.models import AnchorRanges2D
from estimators.poly import Polyhedral
from tests.support.est_helpers import HOVER_XY_M, SIGMA_M, run_stream

ONSET, STEPS = 10, 100


def _attack(offsets: list[float]):
    off = np.asarray(offsets, dtype=float)
    return lambda k, z: off if k >= ONSET else np.zeros(8)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(
    xy=st.tuples(st.floats(0.5, 4.5), st.floats(0.5, 4.5)),
    noise=st.lists(st.floats(-0.3, 0.3), min_size=8, max_size=8),
)
def test_an_honest_readings_polygon_contains_the_truth(anchors8: AnchorRanges2D, xy, noise) -> None:
    """Noise inside k sigma: the truth satisfies every reading's circumscribed polygon (the set guarantee)."""
    est = Polyhedral(anchors8)
    truth = np.array(xy)
    z = anchors8.h(truth) + np.array(noise)
    b = est.offsets(z, None)
    assert np.all(est.normals @ truth <= b + 1e-9)


def test_clean_hover_is_coarse_but_bounded(anchors8: AnchorRanges2D) -> None:
    run = run_stream("poly", anchors8, HOVER_XY_M, _attack([0.0] * 8), STEPS, seed=3)
    rmse = float(np.sqrt(np.mean(run.err_m**2)))
    assert 0.02 < rmse < 2.5 * SIGMA_M and not run.alarm.any()
    assert sum(len(a) for a in run.attacked) <= 0.01 * 8 * STEPS


def test_shortened_readings_are_dropped_and_named(anchors8: AnchorRanges2D) -> None:
    """A reading shortened so far that the polygons cannot all meet is dropped; one shortened less (0.7 m,
    7 sigma) is often kept and pulls the centre instead: the set only has to stay non-empty."""
    run = run_stream("poly", anchors8, HOVER_XY_M, _attack([0, -1.5, 0, 0, -1.0, 0, 0, 0]), STEPS, seed=3)
    late = slice(ONSET + 10, None)
    assert np.max(run.err_m[late]) < 5 * SIGMA_M and not run.alarm[late].any()
    assert np.mean([u.isdisjoint({1, 4}) for u in run.used[late]]) > 0.9
    assert np.mean([a == {1, 4} for a in run.attacked[late]]) > 0.9 and all(a <= {1, 4} for a in run.attacked)
    milder = run_stream("poly", anchors8, HOVER_XY_M, _attack([0, -1.5, 0, 0, -0.7, 0, 0, 0]), STEPS, seed=3)
    assert np.mean([4 in u for u in milder.used[late]]) > 0.1  # kept at times: the blind band of a set method


def test_lengthened_readings_pass_unnamed(anchors8: AnchorRanges2D) -> None:
    """The documented blind spot: a longer range only loosens its own polygon, so nothing is dropped or named;
    inside the anchor square the estimate stays coarse but bounded. SecEKF names the same links."""
    attack = _attack([0, 1.0, 0, 0, 0.7, 0, 0, 0])
    run = run_stream("poly", anchors8, HOVER_XY_M, attack, STEPS, seed=3)
    late = slice(ONSET + 10, None)
    assert not any(run.attacked[late]) and np.max(run.err_m[late]) < 5 * SIGMA_M
    sec = run_stream("secekf", anchors8, HOVER_XY_M, attack, STEPS, seed=3)
    assert np.mean([{1, 4} <= a for a in sec.attacked[late]]) > 0.9


def test_three_shortened_readings_raise_the_alarm_and_are_named(anchors8: AnchorRanges2D) -> None:
    run = run_stream("poly", anchors8, HOVER_XY_M, _attack([-1.0, -1.0, -1.0, 0, 0, 0, 0, 0]), STEPS, seed=3)
    late = slice(ONSET + 10, None)
    assert run.alarm[late].all()
    assert np.mean([a == {0, 1, 2} for a in run.attacked[late]]) > 0.9


def test_poly_runs_only_on_the_two_dimensional_anchor_model() -> None:
    from estimators.scenario_models import anchor_model
    from secuav_common.scenario import load_scenario

    scenario = load_scenario("anchors8")
    assert "poly" in estimators.names(anchor_model(scenario, dims=2))
    assert "poly" not in estimators.names(anchor_model(scenario))

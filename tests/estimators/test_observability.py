"""How many liars a layout can correct, from its geometry (estimators/observability.py), and ties at run time."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

import estimators
from estimators.models import AnchorRanges2D, AnchorRanges3D, AnchorRangesHeight, LinearModel, TwoVehicleRanges
from estimators.observability import linear_correctable
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M

# Four anchors on the line north = 2.5 m across the middle, four at the corners (issue 26's layout).
COLLINEAR_NED_M = np.array(
    [[2.5, 0.0, -1.0], [2.5, 5 / 3, -1.0], [2.5, 10 / 3, -1.0], [2.5, 5.0, -1.0],
     [0.0, 0.0, -1.0], [5.0, 0.0, -1.0], [5.0, 5.0, -1.0], [0.0, 5.0, -1.0]]
)  # fmt: skip
# The same four on the edge north = 0 instead: their mirror falls outside the box for positions far from the edge.
EDGE_NED_M = COLLINEAR_NED_M - np.array([2.5, 0.0, 0.0])
EDGE_NED_M[4:] = [[5.0, 0.0, -1.0], [5.0, 5.0, -1.0], [2.5, 1.0, -1.0], [3.5, 4.0, -1.0]]


def test_the_seed_layouts_keep_two() -> None:
    """Counting sensors and the geometry agree on the seed's layouts: nothing changes for them."""
    for model in (
        AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M),
        AnchorRanges3D.build(ANCHORS8_NED_M, SIGMA_M),
        AnchorRangesHeight.build_with_laser(ANCHORS8_NED_M, SIGMA_M, 0.03),
        TwoVehicleRanges.build(ANCHORS8_NED_M, SIGMA_M),
    ):
        assert model.max_correctable == 2, type(model).__name__
        assert model.support().reason == ""


@pytest.mark.parametrize("build", [
    lambda: AnchorRanges2D.build(COLLINEAR_NED_M, SIGMA_M),
    lambda: AnchorRangesHeight.build_with_laser(COLLINEAR_NED_M, SIGMA_M, 0.03),
])  # fmt: skip
def test_four_collinear_anchors_support_one_liar_not_two(build) -> None:
    model = build()
    assert model.support().count_bound == 2  # what counting sensors said
    assert model.max_correctable == 1
    with pytest.raises(ValueError) as err:
        estimators.create("secekf", model, s=2)
    line = str(err.value)
    assert "\n" not in line and "s=2" in line and "correct, 1:" in line and "0, 1, 2, 3" in line
    assert estimators.create("secekf", model).s == 1  # the default follows the geometry


def _second_solutions(model: AnchorRanges2D, keep: tuple[int, ...], x: np.ndarray) -> float:
    """Brute force: the farthest position in the box whose readings of ``keep`` equal those of x (multistart
    Gauss-Newton from a grid over the box); 0 when x is the only one."""
    idx = list(keep)
    target = model.h(x)[idx]
    lo, hi = model.bounds_m
    y = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 7), np.linspace(lo[1], hi[1], 7)), -1).reshape(-1, 2)
    for _ in range(25):  # every start at once
        h, jac = model.h_jac(y)
        r, J = h[:, idx] - target, jac[:, idx]
        normal = np.einsum("spi,spj->sij", J, J) + 1e-12 * np.eye(2)
        y = y - np.linalg.solve(normal, np.einsum("spi,sp->si", J, r)[..., None])[..., 0]
    ok = np.all((y > lo + 0.05) & (y < hi - 0.05), axis=1) & (np.max(np.abs(model.h(y)[:, idx] - target), 1) < 1e-7)
    return float(np.max(np.linalg.norm(y[ok] - x, axis=1), initial=0.0))


@pytest.mark.parametrize("anchors", [ANCHORS8_NED_M, COLLINEAR_NED_M])
def test_the_geometry_agrees_with_a_brute_force_search_for_second_solutions(anchors: np.ndarray) -> None:
    """For s = 2, some p - 2s = 4 readings admit a second position more than 4 sigma away (inside the box, from a
    position of the flight region) exactly when the check says the layout does not support s = 2."""
    model = AnchorRanges2D.build(anchors, SIGMA_M)
    region = [np.array([n, e]) for n in (0.5, 1.5, 3.5, 4.5) for e in (0.5, 2.5, 4.5)]
    ambiguous = any(
        _second_solutions(model, keep, x) > 4 * SIGMA_M for keep in itertools.combinations(range(8), 4) for x in region
    )
    assert ambiguous == (model.max_correctable < 2)


# Cross-checks of the exact linear test against the examples of two open implementations (matrices read from
# their repositories; the expected answers worked out by hand here).


def test_linear_ugv_example_of_imhotep_smt() -> None:
    """Imhotep-SMT's UGV example: position and velocity, the velocity measured twice, one attacked sensor, the
    position sensor declared safe. Without the safe sensor no sensor set survives removing one (the two velocity
    sensors cannot see the position); with it, any two removals leave the position sensor, which with the
    dynamics observes both states."""
    A = np.array([[1.0, 0.0099], [0.0, 0.9876]])
    C = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])
    assert linear_correctable(C, A) == (0, (2,))  # removing the position sensor leaves a velocity only
    assert linear_correctable(C, A, safe=(0,))[0] == 1
    # A snapshot (no dynamics) cannot even use the position sensor alone: the LinearModel's own test says 0.
    assert LinearModel.build(C).max_correctable == 0


def test_linear_drone_model_of_px4_secure_state_reconstruction() -> None:
    """px4-secure-state-reconstruction's drone model: two axes, each a position and a first-order velocity
    (tau = 5 s, 20 Hz), every state measured by two sensors, s = 2 assumed there. Removing the four position
    sensors leaves velocities only, so not even one liar is correctable by the 2s criterion (that brute-force
    reconstruction returns every candidate state, not one); three position sensors per axis support one."""
    tau, ts = 5.0, 0.05
    Ac = np.array([[0, 1, 0, 0], [0, -1 / tau, 0, 0], [0, 0, 0, 1], [0, 0, 0, -1 / tau]])
    A = scipy.linalg.expm(Ac * ts)
    C = np.vstack([np.eye(4), np.eye(4)])
    assert linear_correctable(C, A)[0] == 0
    assert LinearModel.build(C).support().count_bound == 2  # counting sensors would have claimed two
    positions = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]] * 3)
    assert linear_correctable(positions, A)[0] == 1
    assert linear_correctable(positions)[0] == 0  # without the dynamics positions never show velocities


def test_linear_model_is_exact_on_generic_and_rank_deficient_matrices() -> None:
    rng = np.random.default_rng(3)
    generic = rng.standard_normal((7, 2))  # any two rows have full rank: 7 - 2s >= 2
    assert LinearModel.build(generic).max_correctable == 2
    pair = np.vstack([generic[:6], 3 * generic[0]])  # two parallel rows: any 3 rows still have rank 2
    assert LinearModel.build(pair).max_correctable == 2
    three = np.vstack([generic[:5], generic[0], -generic[0]])  # three parallel: keeping just those 3 fails
    assert LinearModel.build(three).max_correctable == 1


def _mirror_run(model: AnchorRanges2D, truth: np.ndarray, liars: list[int], mirror: np.ndarray, seed: int):
    rng = np.random.default_rng(seed)
    est = estimators.create("secekf", model, s=2)
    out = []
    for k in range(40):
        z = model.h(truth) + SIGMA_M * rng.standard_normal(8)
        z[liars] = model.h(mirror)[liars] + SIGMA_M * rng.standard_normal(len(liars))
        out.append(est.step(0.1 * k, z))
    return out


def test_a_tie_outside_the_checked_region_is_flagged_ambiguous_not_claimed_valid() -> None:
    """Four anchors on the edge north = 0: over a region at least 1.2 m from the edge their mirror falls outside
    the box, so s = 2 is accepted there. At 0.5 m from the edge (outside that region) two liars reporting the
    mirror's ranges tie with the truth: no step may be claimed valid, and the ties are named ambiguous."""
    region = (np.array([1.2, 0.0]), np.array([5.0, 5.0]))
    model = AnchorRanges2D.build(EDGE_NED_M, SIGMA_M, region_m=region)
    assert model.max_correctable == 2
    assert AnchorRanges2D.build(EDGE_NED_M, SIGMA_M).max_correctable == 1  # the whole anchor box: the edge too
    truth, mirror = np.array([0.5, 2.5]), np.array([-0.5, 2.5])
    for seed in range(3):
        out = _mirror_run(model, truth, [4, 6], mirror, seed)
        assert not any(o.valid and np.linalg.norm(o.position_m - truth) > 0.5 for o in out), seed
        assert sum(o.ambiguous for o in out) >= 30, seed
        clean = _mirror_run(model, truth, [], mirror, seed)  # the mirror needs two liars, the truth none
        assert sum(o.valid for o in clean) >= 34 and not any(o.ambiguous for o in clean), seed


def test_scenario_models_check_the_hover_band() -> None:
    """A scenario's model is checked over its anchors' box within 0.5 m of the hold height: the seed's layout
    keeps 2, the collinear one gets 1, and a hover band reaching down to 1.5 m (where the anchor plane's mirror
    lies above the ground and only the laser tells them apart) would leave none."""
    from estimators.scenario_models import anchor_model
    from secuav_common.scenario import load_scenario

    model = anchor_model(load_scenario("anchors8"))
    assert model.region_m is not None and model.region_m[0][2] == pytest.approx(-3.0)
    assert model.max_correctable == 2
    studies = Path(__file__).resolve().parents[2] / "studies"
    assert anchor_model(load_scenario(studies / "scenarios" / "collinear4.yaml")).max_correctable == 1
    low = (np.array([0.0, 0.0, -3.5]), np.array([5.0, 5.0, -1.5]))
    assert AnchorRangesHeight.build_with_laser(ANCHORS8_NED_M, SIGMA_M, 0.03, region_m=low).max_correctable == 0


def test_on_the_ground_before_take_off_nothing_is_ambiguous() -> None:
    """The laser has no reading below its minimum range, and the coplanar anchors' mirror is 2 m up: with every
    reading explained nothing lies, the prior picks the ground, and the estimate stays valid (the live stage
    must not mark the vehicle's position unknown before it takes off)."""
    from estimators.scenario_models import anchor_model
    from secuav_common.scenario import load_scenario

    model = anchor_model(load_scenario("anchors8"))
    est = estimators.create("secekf", model)
    rng = np.random.default_rng(0)
    for k in range(30):
        z = model.h(np.array([2.5, 2.5, 0.0])) + model.sigma_m * rng.standard_normal(9)
        z[8] = np.nan
        out = est.step(0.1 * k, z)
        assert not out.ambiguous and out.valid and abs(out.position_m[2]) < 0.3, (k, out)

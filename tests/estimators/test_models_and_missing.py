"""Missing readings, and every model (scalar group, 3-D, two vehicles, linear) under attack."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import estimators
from estimators.models import AnchorRanges2D, AnchorRanges3D, LinearModel, ScalarGroup, TwoVehicleRanges
from tests.support.est_helpers import ANCHORS8_NED_M, HOVER_XY_M, SECURE, SIGMA_M, run_stream

ALL = tuple(estimators.names(AnchorRanges2D.build(ANCHORS8_NED_M)))


def test_names_cover_the_issue() -> None:
    every = {"ls", "ekf", "l1", "secekf", "secopt", "recap", "rarse", "poly", "l0", "milp", "marzullo"}
    assert set(estimators.registry.builtin_names()) == every
    assert every <= set(estimators.names())  # installed plugins come after them
    assert set(ALL) == set(estimators.names()) - {"marzullo"}  # interval fusion needs one measured quantity


@pytest.mark.parametrize("name", SECURE)
def test_dropped_sensors_with_an_attack(anchors8: AnchorRanges2D, name: str) -> None:
    """Two links drop out at random each step while one link is attacked: still fine."""
    rng = np.random.default_rng(4)
    est = estimators.create(name, anchors8)
    hits = 0
    for k in range(60):
        z = anchors8.h(HOVER_XY_M) + SIGMA_M * rng.standard_normal(8)
        z[6] += 4.0
        drop = rng.choice([0, 1, 2, 3, 4, 5, 7], size=2, replace=False)
        z[drop] = np.nan
        out = est.step(0.1 * k, z)
        assert (out.used.isdisjoint(drop.tolist()) and 6 not in out.used) or out.alarm
        if k >= 10:
            assert np.linalg.norm(out.position_m - HOVER_XY_M) < 5 * SIGMA_M, (k, out)
            hits += 6 in out.attacked
    assert hits >= 0.9 * 50


@pytest.mark.parametrize("name", ALL)
def test_all_missing_does_not_crash_and_recovers(anchors8: AnchorRanges2D, name: str) -> None:
    rng = np.random.default_rng(5)
    est = estimators.create(name, anchors8)
    first = est.step(0.0, np.full(8, np.nan))
    assert not first.ok and np.all(np.isnan(first.position_m))
    for k in range(1, 20):
        z = anchors8.h(HOVER_XY_M) + SIGMA_M * rng.standard_normal(8)
        if k % 5 == 0:
            z[:] = np.nan  # a whole frame lost: hold, do not jump
        out = est.step(0.1 * k, z)
        assert out.ok and np.linalg.norm(out.position_m - HOVER_XY_M) < 5 * SIGMA_M, (name, k)


@pytest.mark.parametrize("name", SECURE)
def test_wall_group_two_of_five_attacked(wall_group: ScalarGroup, name: str) -> None:
    """The proxy's secure stage runs these live on the wall group: two of five lie consistently."""

    def attack(k: int, z: np.ndarray) -> np.ndarray:
        off = np.zeros(5)
        if k >= 20:
            off[[0, 1]] = 1.5  # both lasers say the wall is 1.5 m further
        return off

    run = run_stream(name, wall_group, np.array([2.5]), attack, 60, seed=6)
    assert np.max(run.err_m[30:]) < 0.15
    assert all({0, 1} <= a for a in run.attacked[30:])
    assert not run.alarm[30:].any()


@pytest.mark.parametrize("name", ("ls", "ekf"))
def test_wall_group_baselines_are_dragged(wall_group: ScalarGroup, name: str) -> None:
    def attack(k: int, z: np.ndarray) -> np.ndarray:
        return np.array([1.5, 1.5, 0, 0, 0]) if k >= 20 else np.zeros(5)

    run = run_stream(name, wall_group, np.array([2.5]), attack, 60, seed=6)
    assert np.median(run.err_m[30:]) > 0.5


@pytest.mark.parametrize("name", SECURE)
def test_3d_ranges_one_attacked(name: str) -> None:
    # Anchors at two heights so the vertical is observable (posts and ceiling).
    anchors = ANCHORS8_NED_M.copy()
    anchors[1::2, 2] = -4.0
    model = AnchorRanges3D.build(anchors, SIGMA_M)
    # Counting says 2, but the four anchors at 4 m are coplanar: a vehicle under them and its mirror image above
    # their plane fit the same four ranges, so two liars among the others would tie (observability.py).
    assert model.support().count_bound == 2 and model.max_correctable == 1
    truth = np.array([2.0, 3.0, -2.5])

    def attack(k: int, z: np.ndarray) -> np.ndarray:
        off = np.zeros(8)
        if k >= 20:
            off[3] = 3.0
        return off

    run = run_stream(name, model, truth, attack, 50, seed=8)
    assert np.max(run.err_m[32:]) < 0.6
    assert sum(3 in a for a in run.attacked[32:]) >= 0.9 * 18


@pytest.mark.parametrize("name", SECURE)
def test_two_vehicles_inter_range_attacked(name: str) -> None:
    model = TwoVehicleRanges.build(ANCHORS8_NED_M, SIGMA_M, vehicle_z_ned_m=(-2.5, -2.5))
    truth = np.array([4.0, 4.0, 1.5, 2.0])
    assert model.p == 17 and model.max_correctable == 2

    def attack(k: int, z: np.ndarray) -> np.ndarray:
        off = np.zeros(17)
        if k >= 20:
            off[16] = -1.5  # the inter-vehicle range claims they are closer
            off[2] = 2.0  # and one of vehicle 1's anchor links lies
        return off

    run = run_stream(name, model, truth, attack, 50, seed=9)
    assert np.max(run.err_m[32:]) < 0.5
    assert sum({2, 16} <= a for a in run.attacked[32:]) >= 0.9 * 18


@pytest.mark.parametrize("name", SECURE)
def test_linear_model(name: str) -> None:
    rng = np.random.default_rng(10)
    model = LinearModel.build(rng.standard_normal((7, 2)), 0.05)
    assert model.max_correctable == 2 and model.min_sensors == 2
    truth = np.array([1.0, -2.0])

    def attack(k: int, z: np.ndarray) -> np.ndarray:
        off = np.zeros(7)
        if k >= 20:
            off[[1, 5]] = [5.0, -3.0]
        return off

    run = run_stream(name, model, truth, attack, 50, seed=11)
    assert np.max(run.err_m[32:]) < 0.3
    assert sum({1, 5} <= a for a in run.attacked[32:]) >= 0.9 * 18


def test_model_geometry_and_jacobians() -> None:
    rng = np.random.default_rng(12)
    models = [
        AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M),
        AnchorRanges3D.build(ANCHORS8_NED_M, SIGMA_M),
        ScalarGroup.build([0.1, 0.2, 0.3]),
        LinearModel.build(rng.standard_normal((5, 3))),
        TwoVehicleRanges.build(ANCHORS8_NED_M, SIGMA_M),
    ]
    for model in models:
        pos = model.clip(model.initial_pos() + 0.3 * rng.standard_normal(model.d))
        jac = model.jac(pos[None, :])[0]
        step = 1e-6
        numeric = np.stack(
            [(model.h(pos + step * e) - model.h(pos - step * e)) / (2 * step) for e in np.eye(model.d)], axis=1
        )
        np.testing.assert_allclose(jac, numeric, atol=1e-6, err_msg=type(model).__name__)
    assert AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M).max_correctable == 2  # estimators/README.md#api
    assert ScalarGroup.build([0.1] * 5).max_correctable == 2
    assert ScalarGroup.build([0.1] * 4).max_correctable == 1


def test_bad_parameters_are_refused(anchors8: AnchorRanges2D) -> None:
    with pytest.raises(ValueError, match="s=8"):
        estimators.create("secekf", anchors8, s=8)
    with pytest.raises(ValueError, match="alpha"):
        estimators.create("secopt", anchors8, alpha=1.5)
    with pytest.raises(ValueError, match="expected 8 readings"):
        estimators.create("ekf", anchors8).step(0.0, np.zeros(7))
    with pytest.raises(ValueError, match="positive"):
        ScalarGroup.build([0.1, 0.0])


def test_closed_form_trilateration_is_exact_on_clean_ranges() -> None:
    from estimators.bank import subset_masks

    model = AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M)
    truth = np.array([2.19, 2.7])
    masks = subset_masks(8, 3)
    fixes = model.minimal_fixes(model.h(truth), masks)
    idx = np.nonzero(masks)[1].reshape(-1, 3)
    xy = ANCHORS8_NED_M[:, :2]
    u, v = xy[idx[:, 1]] - xy[idx[:, 0]], xy[idx[:, 2]] - xy[idx[:, 0]]
    area = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    proper = area > 1e-6  # collinear triples have no unique fix
    np.testing.assert_allclose(fixes[proper], np.broadcast_to(truth, fixes[proper].shape), atol=1e-9)


def test_the_formation_gives_each_vehicle_its_own_tolerance() -> None:
    from estimators.scenario_models import anchor_model, two_vehicle_model
    from secuav_common.scenario import load_scenario

    single = anchor_model(load_scenario("anchors8"))
    assert single.honest_subsets(2).shape == (36, 9)  # C(9, 2): any two of the eight ranges and the laser
    pair = two_vehicle_model(load_scenario("formation"))
    masks = pair.honest_subsets(2)
    # Two of each vehicle's eight anchor links, and the inter-vehicle range in or out: 28 * 28 * 2.
    assert masks.shape == (1568, 17)
    left_out = ~masks
    assert (left_out[:, :8].sum(axis=1) == 2).all() and (left_out[:, 8:16].sum(axis=1) == 2).all()
    assert pair.within_tolerance(np.array([1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1], dtype=bool), 2)
    assert not pair.within_tolerance(np.array([1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], dtype=bool), 2)


@given(
    sizes=st.lists(st.integers(1, 6), min_size=1, max_size=3),
    tolerances=st.lists(st.integers(0, 7), min_size=3, max_size=3),
)
def test_subsets_are_counted_exactly_without_building_them(sizes: list[int], tolerances: list[int]) -> None:
    from estimators.models import leave_out_masks, subset_count

    groups, start = [], 0
    for size, k in zip(sizes, tolerances, strict=False):  # a group may be no larger than its tolerance
        groups.append((tuple(range(start, start + size)), k))
        start += size
    assert subset_count(tuple(groups)) == leave_out_masks(start + 1, tuple(groups)).shape[0]


def test_listing_estimators_on_a_large_ring_does_not_enumerate_its_subsets() -> None:
    from estimators import registry
    from estimators.models import leave_out_masks

    rng = np.random.default_rng(1)
    angle = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    ring = AnchorRanges3D.build(np.c_[10 * np.cos(angle), 10 * np.sin(angle), -rng.uniform(0.5, 4.0, 24)])
    assert ring.max_correctable == 9
    assert ring.subset_count(9) == 1_307_504  # C(24, 9): what l0 would have to fit each step
    built = leave_out_masks.cache_info().misses
    listed = registry.names(ring)
    assert "l0" not in listed and "ekf" in listed
    assert leave_out_masks.cache_info().misses == built  # counted, not built (that took 10 s)

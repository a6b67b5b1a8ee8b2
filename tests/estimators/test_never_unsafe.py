"""Never unsafe (issue 34, item 4): no estimator reports a position outside what the anchors' geometry and the
motion bound allow (estimators.envelope), whatever the readings do: gross errors, long gaps, bursts of NLOS.
A filter that diverges raises an alarm, marks its estimate invalid and starts again. Hypothesis draws the
trajectory and the faults; derandomized, so every run is the same."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import estimators
from estimators.envelope import MAX_SPEED_MPS, SLACK_M
from estimators.models import AnchorRanges2D, AnchorRangesHeight
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M

BUILT_INS = ("ls", "ekf", "l1", "secekf", "secopt", "recap", "rarse", "poly", "l0", "milp")
STEPS = 80
DT_S = 0.1
PROPS = settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))

gross = st.lists(
    st.tuples(st.integers(0, STEPS - 1), st.integers(0, 7), st.sampled_from([0.0, -3.0, 25.0, 400.0, 1e6])),
    max_size=12,
)  # (step, link, value): a reading replaced by a wild value
gap = st.tuples(st.integers(5, STEPS - 10), st.integers(3, 20), st.floats(0.5, 8.0))  # (start, steps, seconds each)
nlos = st.lists(
    st.tuples(st.integers(0, STEPS - 1), st.integers(3, 30), st.lists(st.integers(0, 7), min_size=1, max_size=3,
                                                                        unique=True), st.floats(0.3, 3.0)),
    max_size=3,
)  # (start, steps, links, excess metres): the ranges read long while the line of sight is blocked
path = st.tuples(st.floats(0.0, 1.8), st.floats(-0.4, 0.4), st.floats(0.0, 6.3))  # radius, rad/s, phase


def _truth(t: float, radius: float, omega: float, phase: float) -> np.ndarray:
    return np.array([2.5 + radius * np.cos(omega * t + phase), 2.5 + radius * np.sin(omega * t + phase)])


def _stream(model: AnchorRanges2D, faults: dict, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, readings, truth): 10 Hz, with a long gap (no readings, the clock running on) and the faults."""
    rng = np.random.default_rng(seed)
    start, length, each_s = faults["gap"]
    dts = np.full(STEPS, DT_S)
    dts[start : start + length] = each_s
    t = np.cumsum(dts)
    truth = np.array([_truth(tk, *faults["path"]) for tk in t])
    z = np.array([model.h(p) for p in truth]) + SIGMA_M * rng.standard_normal((STEPS, model.p))
    z[start : start + length] = np.nan
    for k0, n, links, excess in faults["nlos"]:
        z[k0 : k0 + n, links] += excess
    for k, link, value in faults["gross"]:
        z[k, link] = value
    return t, z, truth


def _check_envelope(model: AnchorRanges2D, name: str, t: np.ndarray, z: np.ndarray) -> list:
    est = estimators.create(name, model)
    lo, hi = np.asarray(model.bounds_m[0]) - SLACK_M, np.asarray(model.bounds_m[1]) + SLACK_M  # the box + slack
    last = None
    outs = []
    for k in range(t.size):
        out = est.step(float(t[k]), z[k])
        outs.append(out)
        if not out.ok:
            continue
        pos = out.position_m
        assert np.isfinite(pos).all() and np.all(pos >= lo - 1e-9) and np.all(pos <= hi + 1e-9), (k, pos)
        if last is not None:
            reach = MAX_SPEED_MPS * (t[k] - last[1]) + SLACK_M
            assert np.all(np.abs(pos - last[0]) <= reach + 1e-9), (k, pos, last)
        if out.reinitialised:
            assert out.alarm and not out.valid
        if out.valid:
            last = (pos.copy(), float(t[k]))
    return outs


@pytest.mark.parametrize("name", BUILT_INS)
@PROPS
@given(path=path, gross=gross, gap=gap, nlos=nlos, seed=st.integers(0, 2**16))
def test_no_position_outside_the_geometry_and_the_motion_bound(
    anchors8: AnchorRanges2D, name: str, path: tuple, gross: list, gap: tuple, nlos: list, seed: int
) -> None:
    t, z, _ = _stream(anchors8, {"path": path, "gross": gross, "gap": gap, "nlos": nlos}, seed)
    _check_envelope(anchors8, name, t, z)


@pytest.mark.parametrize("name", ("ls", "ekf", "secekf", "recap", "rarse", "l0"))
@settings(max_examples=4, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(gross=gross, seed=st.integers(0, 2**16))
def test_in_space_with_the_laser_too(name: str, gross: list, seed: int) -> None:
    """The 3-D model (the downward laser a reading): its box holds the heights as well."""
    model = AnchorRangesHeight.build_with_laser(ANCHORS8_NED_M, SIGMA_M, laser_sigma_m=0.05)
    rng = np.random.default_rng(seed)
    est = estimators.create(name, model)
    lo, hi = np.asarray(model.bounds_m[0]) - SLACK_M, np.asarray(model.bounds_m[1]) + SLACK_M
    for k in range(50):
        truth = np.array([2.5 + 0.5 * np.sin(0.1 * k), 2.5, -2.5])
        z = model.h(truth) + model.sigma_m * rng.standard_normal(model.p)
        for step, link, value in gross:
            if step == k:
                z[link] = value
        out = est.step(0.1 * k, z)
        if out.ok:
            assert np.all(out.position_m >= lo - 1e-9) and np.all(out.position_m <= hi + 1e-9)


def test_a_filter_that_coasts_off_the_map_alarms_and_starts_again(anchors8: AnchorRanges2D) -> None:
    """The EKF learns a velocity of 1 m/s, then loses every reading for a minute: its prediction would run 60 m
    off and report it as valid. Now the step that leaves the box (or where its covariance says it no longer
    knows) is an alarm, not valid, on the envelope; it has no estimate until readings return, then starts again
    from them at noise level."""
    rng = np.random.default_rng(1)
    est = estimators.create("ekf", anchors8)
    t = 0.0
    for k in range(30):  # 3 s eastward at 1 m/s
        t = 0.1 * k
        truth = np.array([2.5, 1.0 + t])
        assert est.step(t, anchors8.h(truth) + SIGMA_M * rng.standard_normal(8)).valid
    outs = []
    for _ in range(60):  # a minute without readings, one empty step a second
        t += 1.0
        outs.append(est.step(t, np.full(8, np.nan)))
    caught = [o for o in outs if o.reinitialised]
    assert len(caught) == 1 and caught[0].alarm and not caught[0].valid
    lo, hi = anchors8.bounds_m[0] - SLACK_M, anchors8.bounds_m[1] + SLACK_M
    for o in outs:
        assert not o.ok or (np.all(o.position_m >= lo) and np.all(o.position_m <= hi))
        assert not (o.ok and o.valid and np.linalg.norm(o.position_m - np.array([2.5, 4.0])) > 8.0)
    after = outs[outs.index(caught[0]) + 1 :]
    assert after and not any(o.ok for o in after)  # no estimate without readings, rather than a guess
    back = est.step(t + 0.1, anchors8.h(np.array([2.5, 2.0])) + SIGMA_M * rng.standard_normal(8))
    assert back.ok and back.valid and np.linalg.norm(back.position_m - np.array([2.5, 2.0])) < 0.3


def test_a_step_beyond_the_motion_bound_is_not_valid(anchors8: AnchorRanges2D) -> None:
    """Every reading at once says the vehicle jumped 3 m in 0.1 s (more than 10 m/s x 0.1 s + 1 m): least
    squares follows the readings, but the envelope reports the jump as not valid, on its bound; once the bound
    has grown past the new place (0.2 s later) the fix is valid again."""
    est = estimators.create("ls", anchors8)
    here, there = np.array([2.5, 1.0]), np.array([2.5, 4.0])
    assert est.step(0.0, anchors8.h(here)).valid
    jump = est.step(0.1, anchors8.h(there))
    assert jump.reinitialised and jump.alarm and not jump.valid
    assert jump.position_m[1] == pytest.approx(1.0 + MAX_SPEED_MPS * 0.1 + SLACK_M)
    assert est.step(0.3, anchors8.h(there)).valid

"""estimators.offsets behind a calibration window: offsets that wander with the room are followed, honest links
stay unnamed at the promised rate, and a ramp is named before it grows large (a slow one at the drift bound)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators import noise
from estimators.attribution import Namer
from estimators.models import AnchorRanges2D
from estimators.offsets import BAND_M, RATE_MPS, OffsetTracker
from tests.support.est_helpers import ANCHORS8_NED_M, HOVER_XY_M

RATE_HZ = 10.0
SIGMA = 0.06  # what the window will fit: LIAS's links scatter by 0.05-0.09 m
Z_NED = -2.5
WINDOW_S = 20.0
ONSET_S = 25.0


def _model() -> AnchorRanges2D:
    return AnchorRanges2D.build(ANCHORS8_NED_M, 0.1, vehicle_z_ned_m=Z_NED, sensor_ids=tuple(range(10, 18)))


def _ar(n: int, rng: np.random.Generator, tau_s: float) -> np.ndarray:
    """(n, 8) unit-variance AR(1) errors with time constant ``tau_s``."""
    phi = math.exp(-1.0 / RATE_HZ / tau_s)
    out = np.zeros((n, 8))
    out[0] = rng.standard_normal(8)
    for k in range(1, n):
        out[k] = phi * out[k - 1] + math.sqrt(1.0 - phi * phi) * rng.standard_normal(8)
    return out


def _honest(n: int, seed: int, wander_m: float, share: float = 0.6) -> np.ndarray:
    """Readings of a vehicle circling the hover point: offsets of 0.17 +- 0.06 m that wander by ``wander_m``
    (std, over about 20 s, as LIAS's move with where the tag is) and errors ``share`` correlated over 2 s."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE_HZ
    pos = HOVER_XY_M + 0.8 * np.column_stack([np.cos(0.3 * t), np.sin(0.3 * t)])
    model = _model()
    true = np.array([model.h(p, Z_NED) for p in pos])
    offsets = rng.normal(0.17, 0.06, 8) + wander_m * _ar(n, rng, 20.0)
    err = SIGMA * (math.sqrt(1.0 - share) * rng.standard_normal((n, 8)) + math.sqrt(share) * _ar(n, rng, 2.0))
    return true + offsets + err


def _run(z: np.ndarray, name: str = "secekf", **params) -> tuple[np.ndarray, np.ndarray]:
    est = noise.create(name, _model(), calibration_s=WINDOW_S, **params)
    named = np.zeros(z.shape, dtype=bool)
    alarm = np.zeros(z.shape[0], dtype=bool)
    for k in range(z.shape[0]):
        out = est.step(k / RATE_HZ, z[k], Z_NED)
        named[k, list(out.attacked)] = True
        alarm[k] = out.alarm
    return named, alarm


def _ramp(z: np.ndarray, links: list[int], rate_mps: float) -> np.ndarray:
    t = np.arange(z.shape[0]) / RATE_HZ
    out = z.copy()
    out[:, links] += np.maximum(0.0, t - ONSET_S)[:, None] * rate_mps
    return out


def _first_named_at_m(named: np.ndarray, link: int, rate_mps: float) -> float:
    t = np.arange(named.shape[0]) / RATE_HZ
    hit = np.flatnonzero(named[:, link] & (t >= ONSET_S))
    return math.inf if hit.size == 0 else float((t[hit[0]] - ONSET_S) * rate_mps)


def test_tracker_moves_at_most_its_rate_and_never_past_its_bound() -> None:
    tr = OffsetTracker(3, tau_s=1.0, rate_mps=0.05, bound_m=0.2)
    tr.update(0.0, np.zeros(3), np.ones(3, dtype=bool))
    tr.update(0.1, np.array([10.0, -10.0, 0.001]), np.array([True, True, True]))
    assert tr.delta == pytest.approx([0.005, -0.005, 0.0001])  # rate-bound, rate-bound, dt / tau of the residual
    for k in range(2, 200):
        tr.update(0.1 * k, np.array([10.0, -10.0, np.nan]), np.array([True, False, True]))
    assert tr.delta[0] == pytest.approx(0.2)  # held at the drift bound
    assert tr.delta[1] == pytest.approx(-0.005)  # untrusted: frozen
    assert tr.delta[2] == pytest.approx(0.0001)  # no reading: frozen
    assert tr.most[0] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="tau_s"):
        OffsetTracker(3, tau_s=0.0)


def test_wandering_offsets_name_honest_links_unless_followed() -> None:
    z = _honest(900, seed=13, wander_m=0.06)
    fixed, _ = _run(z, calibration_track=False)
    followed, alarm = _run(z)
    scored = slice(int(WINDOW_S * RATE_HZ) + 10, None)
    assert fixed[scored].any(axis=1).mean() > 0.1  # the window's offsets go stale: the old behaviour
    assert followed[scored].any(axis=1).mean() <= 0.03 and alarm[scored].mean() <= 0.05


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), wander=st.floats(0.0, 0.02))
def test_honest_noise_names_no_link_above_the_rate(seed: int, wander: float) -> None:
    # White errors about wandering offsets; with 30-78 % of the variance correlated over 2 s (LIAS) the synthetic
    # rate reaches 2-3 % on some seeds (on the recordings themselves 0-0.1 %, estimators/README.md).
    z = _honest(700, seed, wander, share=0.0)
    named, alarm = _run(z)
    scored = slice(int(WINDOW_S * RATE_HZ) + 10, None)
    assert named[scored].any(axis=1).mean() <= 0.03
    assert alarm[scored].mean() <= 0.05


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    links=st.lists(st.integers(0, 7), min_size=1, max_size=2, unique=True),
    name=st.sampled_from(["secekf", "secopt", "rarse"]),
)
def test_a_ramp_of_a_tenth_metre_per_second_is_named_before_one_metre(seed: int, links: list[int], name: str) -> None:
    z = _ramp(_honest(int((ONSET_S + 12.0) * RATE_HZ), seed, 0.04), links, 0.1)
    named, _ = _run(z, name)
    for link in links:
        assert _first_named_at_m(named, link, 0.1) < 1.0


def test_a_ramp_under_the_rate_bound_is_named_at_the_drift_bound() -> None:
    # Ten times slower than the ramp above and half the tracker's rate: it would be followed for ever without the
    # drift bound; with it, it shows once it has pushed an offset to the bound.
    rate = RATE_MPS / 2.0
    z = _ramp(_honest(int((ONSET_S + 75.0) * RATE_HZ), 5, 0.02), [3], rate)
    named, _ = _run(z)
    at = _first_named_at_m(named, 3, rate)
    assert at < BAND_M + 0.3


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.floats(0.0, 2.0),  # time since the previous step
            st.lists(st.one_of(st.floats(-1e6, 1e6), st.just(math.nan)), min_size=3, max_size=3),
            st.lists(st.booleans(), min_size=3, max_size=3),
        ),
        max_size=40,
    )
)
def test_no_residuals_move_an_offset_faster_than_its_rate_or_past_its_bound(steps) -> None:
    tr = OffsetTracker(3, tau_s=2.0, rate_mps=0.05, bound_m=0.3)
    t = 0.0
    for dt, resid, trusted in steps:
        before = tr.delta.copy()
        t += dt
        tr.update(t, np.array(resid), np.array(trusted))
        moved = np.abs(tr.delta - before)
        assert np.all(moved <= 0.05 * dt + 1e-12)
        assert np.all(np.abs(tr.delta) <= 0.3 + 1e-12)
        assert np.all(moved[~np.array(trusted)] == 0.0)  # an untrusted link is frozen


def _episode(z: np.ndarray, link: int, size_m: float, start_s: float = 40.0, length_s: float = 6.0) -> np.ndarray:
    """An honest offset that jumps by ``size_m`` within about a second, holds for ``length_s`` and returns (LIAS mid,
    tag 0: link 15 read 0.22-0.31 m short for 6 s)."""
    t = np.arange(z.shape[0]) / RATE_HZ
    rise = np.clip(t - start_s, 0.0, 1.0) - np.clip(t - start_s - length_s, 0.0, 1.0)
    out = z.copy()
    out[:, link] += size_m * rise
    return out


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), link=st.integers(0, 7), sign=st.sampled_from([-1.0, 1.0]))
def test_a_fast_offset_change_inside_the_band_names_nobody(seed: int, link: int, sign: float) -> None:
    # As fast as the ramp to catch, but only a band's worth: the room, not an attack. Beyond the band (and the tests'
    # margin) the same change is named, however briefly it lasts past two readings.
    z = _honest(550, seed, 0.0, share=0.0)
    named, alarm = _run(_episode(z, link, sign * 0.8 * BAND_M))
    scored = slice(int(WINDOW_S * RATE_HZ) + 10, None)
    assert not named[scored, link].any()
    assert named[scored].any(axis=1).mean() <= 0.03 and alarm[scored].mean() <= 0.05
    named, _ = _run(_episode(z, link, sign * (BAND_M + 0.5)))
    assert named[scored, link].any()


def test_without_tracking_the_same_change_is_named_as_before() -> None:
    # --fixed-offsets keeps every residual under judgement: no band, one reading names.
    z = _episode(_honest(550, 3, 0.0, share=0.0), 2, -0.8 * BAND_M)
    named, _ = _run(z, calibration_track=False)
    assert named[int(WINDOW_S * RATE_HZ) + 10 :, 2].any()


@settings(max_examples=200, deadline=None)
@given(
    resid=st.lists(st.one_of(st.floats(-5.0, 5.0), st.just(math.nan)), min_size=4, max_size=4),
    delta=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4),
    bound=st.floats(0.0, 0.5),
    extra=st.floats(0.0, 0.5),
)
def test_beyond_is_the_excess_over_the_band_about_the_window_offset(resid, delta, bound, extra) -> None:
    tr = OffsetTracker(4, tau_s=1.0, rate_mps=0.05, bound_m=bound, band_m=bound + extra)
    tr.delta = np.clip(np.array(delta), -bound, bound)  # the tracker never leaves its drift bound
    r = np.array(resid)
    out = tr.beyond(r)
    assert np.array_equal(np.isnan(out), np.isnan(r))
    ok = np.isfinite(r)
    window = r + tr.delta
    inside = ok & (np.abs(window) <= tr.band_m)
    assert np.all(out[inside] == 0.0)
    # Outside, the excess over the band, with the residual's sign; never more than the residual itself (the band
    # holds every offset the tracker can reach, so it only ever forgives).
    assert np.allclose(np.abs(out[ok & ~inside]), np.abs(window[ok & ~inside]) - tr.band_m)
    assert np.all(out[ok] * window[ok] >= 0.0)
    assert np.all(np.abs(out[ok]) <= np.abs(r[ok]) + 1e-12)


def test_band_narrower_than_the_drift_bound_is_refused() -> None:
    with pytest.raises(ValueError, match="band_m"):
        OffsetTracker(3, bound_m=0.3, band_m=0.2)


def test_the_namer_judges_only_what_the_band_leaves() -> None:
    model = _model()
    pos = np.array([2.0, 1.0])
    z = model.h(pos, Z_NED).copy()
    z[3] += 1.0  # far beyond any gate on its own
    namer = Namer(model, 0.01)
    namer.band = lambda r: np.where(np.isfinite(r), 0.0, r)  # everything is the room
    used = np.ones(model.p, dtype=bool)
    used[3] = False
    for _ in range(5):
        named, _, _ = namer.name(z, used, pos, 0.01 * np.eye(2), Z_NED)
        assert not named.any()
        assert namer.last_resid is not None and abs(namer.last_resid[3]) > 0.5  # the tracker still sees it all
    namer.band = None
    named, _, _ = namer.name(z, used, pos, 0.01 * np.eye(2), Z_NED)
    assert named[3]


def test_the_band_outlives_a_restart() -> None:
    # A diverging filter is re-initialised (base._guard): what the calibration told its tests, the band included,
    # must survive, or a restart would bring back naming on every honest offset change.
    z = _honest(260, 7, 0.0, share=0.0)
    est = noise.create("secekf", _model(), calibration_s=WINDOW_S)
    out = None
    for k in range(z.shape[0]):
        out = est.step(k / RATE_HZ, z[k], Z_NED)
    core = est.core
    assert core.namer.band is not None and core.namer.confirm_steps == noise.CONFIRM_STEPS
    far = replace(out, position_m=np.array([1e3, -1e3]))
    core._guard(far)
    assert far.reinitialised
    assert core.namer.band == est.tracker.beyond and core.namer.confirm_steps == noise.CONFIRM_STEPS
    # results.json says what the tests were told: the band beside the bounds.
    tracking = est.report()["tracking"]
    assert tracking["band_m"] == BAND_M and tracking["bound_m"] == est.tracker.bound_m

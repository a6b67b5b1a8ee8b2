"""The attacks of the science issue, each on a synthetic anchors8 stream: it does what its description says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from attack_profiles import Engine, library
from secuav_common.scenario import Scenario, load_scenario

RATE_HZ = 10.0
IDS = list(range(10, 18))  # the eight anchor links
TRUE_NE = np.array([2.5, 0.6])  # near the edge east = 0


@pytest.fixture(scope="module")
def anchors8() -> Scenario:
    return load_scenario("anchors8")


def _clean(scenario: Scenario, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    anchors = scenario.anchor_positions()
    pos = np.tile([TRUE_NE[0], TRUE_NE[1], -2.5], (n, 1))
    z = np.array([[math.dist(p, anchors[k]) for k in range(8)] for p in pos])
    return (np.arange(n) + 1) / RATE_HZ, z, pos


def _offsets(name: str, scenario: Scenario, seconds: float = 30.0, **params: object) -> tuple[np.ndarray, np.ndarray]:
    t, z, pos = _clean(scenario, int(seconds * RATE_HZ))
    engine = Engine(library.load(name, **params), seed=1, scenario=scenario)
    return t, engine.apply_array(t, z, IDS, position_ned_m=pos) - z


def _col(sid: int) -> int:
    return IDS.index(sid)


def test_stealthy_is_a_multiple_of_each_links_own_sigma(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-stealthy", anchors8)
    after = t >= 5.0
    assert np.allclose(off[after][:, [_col(11), _col(14)]], 3 * 0.10) and np.allclose(off[~after], 0.0)
    assert np.allclose(off[:, [_col(s) for s in IDS if s not in (11, 14)]], 0.0)
    _, off2 = _offsets("anchors-stealthy", anchors8, sigmas=1.5)
    assert np.allclose(off2[t >= 5.0][:, _col(11)], 0.15)


def test_sawtooth_ramps_reset_before_they_grow_large(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-sawtooth", anchors8)
    link = off[:, _col(11)]
    phase = (t - 5.0) % 3.0
    ramping = (t >= 5.0) & (phase < 2.0)
    assert np.allclose(link[ramping], 0.2 * phase[ramping], atol=1e-6)
    assert np.allclose(link[~ramping], 0.0) and link.max() <= 0.4 + 1e-9


def test_moving_set_hands_the_attack_from_pair_to_pair(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-moving-set", anchors8)
    first = off[:, [_col(11), _col(14)]].max(axis=1) > 0
    second = off[:, [_col(12), _col(15)]].max(axis=1) > 0
    for lo, hi, which in ((5, 10, first), (10, 15, second), (15, 20, first), (20, 25, second)):
        window = (t >= lo + 0.05) & (t < hi - 0.05)
        assert which[window].all() and not (first & second)[window].any()
    assert not (first | second)[t < 5.0].any()


def test_mirror_reports_the_mirror_image_across_honest_anchors(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-mirror", anchors8, noise_std_m=0.0)
    anchors = anchors8.anchor_positions()
    mirrored = np.array([TRUE_NE[0], -TRUE_NE[1], -2.5])  # across the line east = 0
    after = t >= 5.0
    _, z, _ = _clean(anchors8, len(t))
    for sid in (14, 15):
        assert np.allclose((z + off)[after, _col(sid)], math.dist(mirrored, anchors[sid - 10]))
    for k in (0, 1, 2):  # the honest anchors on the line measure the lie and the truth alike
        assert math.dist(mirrored, anchors[k]) == pytest.approx(z[0, k])
    _, noisy = _offsets("anchors-mirror", anchors8)
    spread = (noisy - off)[after, _col(14)]
    assert 0.07 < float(np.std(spread)) < 0.13  # the spoofed ranges carry realistic noise


def test_relay_only_lengthens_ranges(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-relay", anchors8)
    attacked = off[t >= 5.0][:, [_col(11), _col(14), _col(16)]]
    assert (attacked >= 0.6 - 1e-9).all() and (attacked <= 0.8 + 1e-9).all() and attacked.std() > 0.03
    assert np.allclose(off[t < 5.0], 0.0)


def test_noise_inflation_stays_near_the_gate(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-noise", anchors8, seconds=120.0)
    link = off[t >= 5.0][:, _col(11)]
    assert float(np.std(link)) == pytest.approx(0.2, rel=0.15) and abs(float(np.mean(link))) < 0.05


def test_overwhelm_attacks_more_links_than_can_be_corrected(anchors8: Scenario) -> None:
    t, off = _offsets("anchors-overwhelm", anchors8)
    hit = (np.abs(off[t >= 10.0]) > 1.0).all(axis=0)
    assert hit.sum() == 4 and hit.sum() > 2  # eight anchors correct at most two in 2-D
    assert np.allclose(off[t < 10.0], 0.0)


def test_replay_repeats_each_links_own_earlier_readings(anchors8: Scenario) -> None:
    n = 300
    t = (np.arange(n) + 1) / RATE_HZ
    rng = np.random.default_rng(2)
    z = 4.0 + 0.1 * rng.standard_normal((n, 8)) + np.linspace(0, 3, n)[:, None]  # the vehicle moves away
    engine = Engine(library.load("anchors-replay"), seed=1, scenario=anchors8)
    out = engine.apply_array(t, z, IDS)
    recorded = (t >= 0.0) & (t < 5.0)
    later = t >= 5.0 + 1e-9
    for sid in (11, 14):
        j = _col(sid)
        assert set(np.round(out[later, j], 9)) <= set(np.round(z[recorded, j], 9))  # only its own past
    assert np.allclose(out[:, _col(12)], z[:, _col(12)])


def test_height_spoof_moves_the_downward_laser(anchors8: Scenario) -> None:
    n = 200
    t = (np.arange(n) + 1) / RATE_HZ
    laser = np.full((n, 1), 2.5)
    out = Engine(library.load("height-spoof"), seed=1, scenario=anchors8).apply_array(t, laser, [0])
    assert np.allclose(out[t >= 5.0, 0] - 2.5, 0.1 * (t[t >= 5.0] - 5.0), atol=1e-6)

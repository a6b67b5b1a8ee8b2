"""Per-link range noise (offset, Gauss-Markov part, Student-t tails, NLOS episodes, gross errors):
the generated statistics match the parameters within sampling bounds, and the old models draw as before."""

from __future__ import annotations

import math
import random
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from flightsim.api import State
from flightsim.sensors import LinkNoise, UwbModel, radio_noise
from secuav_common import scenario as sc
from secuav_common.loading import InputError
from secuav_common.noise_presets import PRESETS
from secuav_common.scenario import RangeNoise, load_scenario, parse_scenario

RATE_HZ = 10.0


def _series(cfg: RangeNoise, n: int, std: float = 0.1, seed: int = 0) -> np.ndarray:
    link = LinkNoise(random.Random(seed), std, cfg)
    return np.array([link.draw(k / RATE_HZ) for k in range(n)])


def _acf(x: np.ndarray, lag: int) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-lag], x[lag:]) / np.dot(x, x))


@settings(max_examples=25, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.floats(0.0, 1.0),
    st.sampled_from([None, RangeNoise(nlos_prob=0.1), RangeNoise(student_t_dof=4, nlos_prob=0.05)]),
)
def test_a_link_without_state_draws_exactly_what_radio_noise_drew(
    seed: int, std: float, cfg: RangeNoise | None
) -> None:
    link, old = LinkNoise(random.Random(seed), std, cfg), random.Random(seed)
    assert not link.stateful
    for k in range(20):
        assert link.draw(k / RATE_HZ) == radio_noise(old, std, cfg)


def test_per_link_offsets_follow_their_mean_and_spread() -> None:
    cfg = RangeNoise(offset_mean_m=0.17, offset_std_m=0.06)
    rng = random.Random(1)
    offsets = np.array([LinkNoise(rng, 0.0, cfg).offset_m for _ in range(2000)])
    # 2000 draws: the sample mean's standard error is 0.06 / sqrt(2000) = 0.0013 m; 4 of them as the bound.
    assert offsets.mean() == pytest.approx(0.17, abs=4 * 0.06 / math.sqrt(2000))
    assert offsets.std() == pytest.approx(0.06, rel=0.08)
    link = LinkNoise(random.Random(2), 0.0, cfg)
    assert all(link.draw(k / RATE_HZ) == link.offset_m for k in range(50))  # constant on its link


def test_the_correlated_part_has_the_stated_autocorrelation() -> None:
    share, tau = 0.8, 2.0
    x = _series(RangeNoise(correlated_share=share, correlation_time_s=tau), 200_000, std=0.1)
    assert x.std() == pytest.approx(0.1, rel=0.05)
    # ACF(lag) = share * exp(-lag / tau); 200k samples span 10,000 correlation times (s.e. about 0.015).
    for lag in (1, 5, 10, 20):
        assert _acf(x, lag) == pytest.approx(share * math.exp(-lag / RATE_HZ / tau), abs=0.05), lag
    white = _series(RangeNoise(offset_mean_m=0.0001), 50_000)
    assert abs(_acf(white, 1)) < 4 / math.sqrt(50_000)


def test_student_t_tails_match_their_quantiles() -> None:
    dof = 5.0
    x = _series(RangeNoise(student_t_dof=dof, offset_mean_m=1e-9), 200_000, std=1.0)
    scale = math.sqrt((dof - 2.0) / dof)  # unit variance
    for q in (0.99, 0.999):
        expected = stats.t.ppf(q, dof) * scale
        assert np.quantile(np.abs(x), 2 * q - 1) == pytest.approx(expected, rel=0.06), q
    assert np.quantile(np.abs(x), 0.999) > 1.15 * stats.norm.ppf(0.9995)  # heavier than the Gaussian's


def test_nlos_episodes_have_their_rate_duration_and_bias() -> None:
    rate, mean_s, bias = 0.05, 1.0, 0.5
    x = _series(
        RangeNoise(nlos_episode_rate_hz=rate, nlos_episode_mean_s=mean_s, nlos_episode_bias_m=bias), 300_000, 0.0
    )
    inside = x > 0
    # Alternating renewal: off for 1/rate on average, on for mean_s, so the share on is 1/21 = 0.048.
    assert inside.mean() == pytest.approx(rate * mean_s / (1 + rate * mean_s), abs=0.008)
    onsets = np.flatnonzero(inside[1:] & ~inside[:-1])
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(int), [0]]))))[::2] / RATE_HZ
    assert len(onsets) / (x.size / RATE_HZ) == pytest.approx(rate / (1 + rate * mean_s), rel=0.1)
    assert runs.mean() == pytest.approx(mean_s + 0.5 / RATE_HZ, rel=0.1)  # framing adds half a tick
    assert x[inside].mean() == pytest.approx(bias, rel=0.1)  # the episode biases average to the stated mean
    assert x.min() >= 0.0  # always a positive excess path


def test_gross_errors_appear_on_their_share_of_readings() -> None:
    prob, std = 0.01, 2.0
    x = _series(RangeNoise(outlier_prob=prob, outlier_std_m=std), 200_000, 0.0)
    share = np.mean(x != 0.0)
    assert share == pytest.approx(prob, abs=4 * math.sqrt(prob * (1 - prob) / x.size))
    assert x[x != 0].std() == pytest.approx(std, rel=0.1)


def test_the_fitted_preset_fills_the_fields_not_given() -> None:
    fitted = RangeNoise(preset="uwb-lias-planar")
    for key, value in PRESETS["uwb-lias-planar"].items():
        assert getattr(fitted, key) == value
    assert RangeNoise(preset="uwb-lias-planar", offset_std_m=0.0).offset_std_m == 0.0
    text = load_scenario("anchors8").model_dump_json().replace('"noise":null', '"noise":{"preset":"made-up"}', 1)
    with pytest.raises(InputError, match=r"vehicles\[0\]\.sensors\.uwb\.noise\.preset"):
        parse_scenario(text, "x.yaml")


def test_the_uwb_model_gives_each_anchor_its_own_offset() -> None:
    anchors = {k: (float(k), 0.0, 0.0) for k in range(8)}
    cfg = sc.UwbRanging(noise_std_m=0.0, rate_hz=10, noise=RangeNoise(offset_mean_m=0.2, offset_std_m=0.1))
    uwb = UwbModel(cfg, anchors, random.Random(5))
    still = (0.0, 0.0, 0.0)
    reads = uwb.sample(State(0.0, (0.0, 0.0, -3.0), still, still, (1.0, 0.0, 0.0, 0.0), still, still))
    offsets = [r.distance_m - math.dist((0.0, 0.0, -3.0), anchors[r.sensor_id - 10]) for r in reads]
    assert offsets == pytest.approx([uwb.links[k].offset_m for k in range(8)])
    assert statistics.pstdev(offsets) > 0.02  # not one shared offset


def test_a_flight_with_the_fitted_preset_has_per_link_offsets() -> None:
    from estimators.scenario_models import anchor_model
    from evaluation.streams import fly

    scenario = load_scenario("anchors8_realnoise")
    stream = fly(scenario, 3, 20.0, RATE_HZ)[1]
    model = anchor_model(scenario, 1, 2)
    z = np.column_stack([stream.readings[i] for i in model.sensor_ids])
    true = np.array([model.h(p[:2], p[2]) for p in stream.truth_ned_m])
    means = np.nanmedian(z - true, axis=0)
    assert 0.08 < means.mean() < 0.26 and means.std() > 0.02  # offsets 0.17 +- 0.062 m across eight links
    assert np.nanstd(z - true - means) == pytest.approx(0.069, rel=0.35)

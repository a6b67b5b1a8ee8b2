"""Radio range noise: the plain Gaussian model is untouched; heavy tails and NLOS excess paths do what they say."""

from __future__ import annotations

import random
import statistics

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flightsim.sensors import radio_noise
from secuav_common.loading import InputError
from secuav_common.scenario import RangeNoise, load_scenario, parse_scenario


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.0))
def test_without_extra_noise_the_draws_are_the_old_gaussian_ones(seed: int, std: float) -> None:
    a, b = random.Random(seed), random.Random(seed)
    for _ in range(20):
        assert radio_noise(a, std, None) == (b.gauss(0.0, std) if std > 0 else 0.0)


def test_student_t_keeps_the_std_and_has_heavier_tails() -> None:
    rng = random.Random(3)
    gauss = [radio_noise(rng, 0.1, None) for _ in range(100_000)]
    heavy = [radio_noise(rng, 0.1, RangeNoise(student_t_dof=4)) for _ in range(100_000)]
    assert statistics.pstdev(heavy) == pytest.approx(0.1, rel=0.08)
    beyond = [sum(abs(x) > 0.4 for x in xs) for xs in (gauss, heavy)]  # 4 sigma
    assert beyond[0] <= 20 and beyond[1] >= 100


def test_nlos_adds_a_positive_excess_path_on_its_share_of_readings() -> None:
    rng = random.Random(4)
    extra = RangeNoise(nlos_prob=0.2, nlos_mean_m=0.5)
    draws = [radio_noise(rng, 0.0, extra) for _ in range(50_000)]
    hit = [x for x in draws if x > 0]
    assert min(draws) == 0.0 and len(hit) / len(draws) == pytest.approx(0.2, abs=0.01)
    assert statistics.mean(hit) == pytest.approx(0.5, rel=0.05)


def test_bundled_nlos_scenario_and_bad_noise_fields() -> None:
    uwb = load_scenario("anchors8_nlos").vehicles[0].sensors.uwb
    assert uwb is not None and uwb.noise == RangeNoise(nlos_prob=0.05, nlos_mean_m=0.3, student_t_dof=4)
    text = load_scenario("anchors8_nlos").model_dump_json().replace('"student_t_dof":4.0', '"student_t_dof":2.0')
    with pytest.raises(InputError, match=r"vehicles\[0\]\.sensors\.uwb\.noise\.student_t_dof"):
        parse_scenario(text, "x.yaml")

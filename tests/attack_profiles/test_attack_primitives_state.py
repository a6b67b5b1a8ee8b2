"""Stateful and random primitives: freeze, replay, delay, intermittent, noise, garbage, coordinated spoof."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest

from attack_profiles import Engine
from secuav_common.scenario import load_scenario
from tests.support.attack_helpers import LOCAL_POSITION_NED, attacked_cm, distance, make_profile, rule, send, started


def test_freeze_holds_last_value_before_window_per_sensor() -> None:
    engine = started(make_profile(rule("freeze", sensor_id=[0, 1], start_s=2, end_s=4)))
    attacked_cm(engine, 0.0, 0, 100)
    attacked_cm(engine, 1.0, 0, 110)
    attacked_cm(engine, 1.5, 1, 500)
    got0 = [attacked_cm(engine, t, 0, cm) for t, cm in ((2.0, 120), (3.0, 130), (4.0, 140))]
    got1 = [attacked_cm(engine, t, 1, cm) for t, cm in ((2.5, 520), (3.5, 530))]
    assert got0 == [110, 110, 140]
    assert got1 == [500, 500]


def test_freeze_without_history_holds_first_value_in_window_and_refreezes_on_repeat() -> None:
    engine = started(make_profile(rule("freeze", start_s=1, end_s=2, repeat_period_s=3)))
    assert [attacked_cm(engine, t, 0, cm) for t, cm in ((1.0, 300), (1.5, 310))] == [300, 300]
    attacked_cm(engine, 3.5, 0, 400)  # outside: passes and is remembered
    assert [attacked_cm(engine, t, 0, cm) for t, cm in ((4.0, 410), (4.9, 420), (5.0, 430))] == [400, 400, 430]


def test_replay_loops_the_recorded_window() -> None:
    engine = started(make_profile(rule("replay", source_start_s=0.0, source_end_s=1.0, start_s=2.0)))
    for i in range(10):  # record 100, 101, ... 109 at t = 0.0 .. 0.9
        assert attacked_cm(engine, i / 10, 0, 100 + i) == 100 + i
    assert attacked_cm(engine, 1.5, 0, 999) == 999  # between: clean
    got = [attacked_cm(engine, 2.0 + tau, 0, 999) for tau in (0.0, 0.35, 0.9, 1.0, 1.25)]
    assert got == [100, 103, 109, 100, 102]


def test_replay_keeps_targets_apart() -> None:
    engine = started(make_profile(rule("replay", sensor_id=None, source_start_s=0.0, source_end_s=1.0, start_s=1.0)))
    attacked_cm(engine, 0.0, 0, 100)
    attacked_cm(engine, 0.0, 1, 200)
    assert attacked_cm(engine, 1.0, 0, 50) == 100  # 50 cm: a reading (the helper's sensor reads 10-4000 cm)
    assert attacked_cm(engine, 1.0, 1, 50) == 200
    assert attacked_cm(engine, 1.0, 2, 50) == 50  # nothing recorded for sensor 2


def test_delay_live_holds_frames_back() -> None:
    engine = started(make_profile(rule("delay", delay_s=0.25, start_s=1)))
    assert send(engine, 0.5, distance(0, 100)).delay_s == 0.0
    action = send(engine, 1.5, distance(0, 100))
    assert action.delay_s == 0.25 and action.fields is None and action.rules == (0,)


def test_delay_offline_shifts_the_stream() -> None:
    engine = started(make_profile(rule("delay", delay_s=0.2, start_s=0.5)))
    t = np.round(np.arange(0.0, 1.0, 0.1), 10)
    z = (np.arange(10.0) + 1.0)[:, None]
    out = engine.apply_array(t, z, [0])[:, 0]
    np.testing.assert_allclose(out, [1, 2, 3, 4, 5, 4, 5, 6, 7, 8])


def test_delay_offline_before_any_history_is_missing() -> None:
    engine = started(make_profile(rule("delay", delay_s=0.5)))
    out = engine.apply_array(np.array([0.0, 0.25, 0.5, 0.75]), np.array([[1.0], [2.0], [3.0], [4.0]]), [0])
    np.testing.assert_allclose(out[:, 0], [np.nan, np.nan, 1.0, 2.0])


def test_intermittent_on_off_pattern() -> None:
    engine = started(make_profile(rule("intermittent", on_s=1.0, off_s=0.5, start_s=10)))
    got = [attacked_cm(engine, t, 0, 100) for t in (9.0, 10.0, 10.99, 11.0, 11.49, 11.5, 12.6)]
    assert got == [100, 100, 100, None, None, 100, None]


def test_noise_gaussian_statistics_and_seed() -> None:
    def values(seed: int) -> list[float]:
        engine = started(make_profile(rule("noise", std=0.5)), seed=seed)
        t = np.arange(4000) * 0.01
        return list(engine.apply_array(t, np.full((4000, 1), 10.0), [0])[:, 0])

    a = values(3)
    assert a == values(3) and a != values(4)
    assert abs(statistics.fmean(a) - 10.0) < 0.05
    assert abs(statistics.stdev(a) - 0.5) < 0.03


def test_noise_uniform_is_bounded_with_the_given_std() -> None:
    engine = started(make_profile(rule("noise", std=0.3, distribution="uniform")))
    out = engine.apply_array(np.arange(4000) * 0.01, np.full((4000, 1), 5.0), [0])[:, 0]
    half = 0.3 * math.sqrt(3)
    assert out.min() >= 5.0 - half and out.max() <= 5.0 + half
    assert abs(out.std() - 0.3) < 0.02


def test_profile_seed_and_engine_seed_both_matter() -> None:
    def first(profile_seed: int, engine_seed: int) -> int | None:
        return attacked_cm(
            started(make_profile(rule("noise", std=1.0), seed=profile_seed), seed=engine_seed), 0, 0, 500
        )

    assert first(1, 1) == first(1, 1)
    assert len({first(1, 1), first(2, 1), first(1, 2)}) == 3


def test_garbage_spans_the_wire_range_and_is_seeded() -> None:
    engine = started(make_profile(rule("garbage")), seed=9)
    values = [attacked_cm(engine, i * 0.01, 0, 250) for i in range(500)]
    assert all(v is not None and 0 <= v <= 65535 for v in values)
    assert max(v for v in values if v is not None) > 50000 and len(set(values)) > 400
    again = started(make_profile(rule("garbage")), seed=9)
    assert values == [attacked_cm(again, i * 0.01, 0, 250) for i in range(500)]


# -- coordinated spoof ------------------------------------------------------------------------------------

ANCHORS8 = load_scenario("anchors8")
ANCHOR_POS = {10 + k: np.array(p) for k, p in ANCHORS8.anchor_positions().items()}


def _spoof_engine(velocity: tuple[float, float, float], offset: tuple[float, float, float] = (0, 0, 0)) -> Engine:
    profile = make_profile(
        rule(
            "coordinated_spoof",
            sensor_id=[11, 14],
            velocity_ned_m_s=list(velocity),
            offset_ned_m=list(offset),
            start_s=1.0,
        )
    )
    engine = Engine(profile, scenario=ANCHORS8)
    engine.activate(0.0)
    return engine


def test_coordinated_spoof_offline_ranges_match_the_fake_position() -> None:
    engine = _spoof_engine((0.1, -0.2, 0.05), offset=(0.3, 0.0, 0.0))
    t = np.arange(0.0, 10.0, 0.1)
    truth = np.column_stack([2.5 + 0.01 * t, 2.5 - 0.02 * t, np.full_like(t, -2.5)])
    ids = list(range(10, 18))
    clean = np.column_stack([np.linalg.norm(truth - ANCHOR_POS[i], axis=1) for i in ids])
    out = engine.apply_array(t, clean, ids, position_ned_m=truth)
    tau = np.clip(t - 1.0, 0.0, None)[:, None]
    fake = truth + np.array([0.3, 0.0, 0.0]) + np.array([0.1, -0.2, 0.05]) * tau
    active = t >= 1.0
    for j, sid in enumerate(ids):
        expected = np.linalg.norm(fake - ANCHOR_POS[sid], axis=1) if sid in (11, 14) else clean[:, j]
        np.testing.assert_allclose(out[active, j], expected[active], atol=1e-9)
        np.testing.assert_allclose(out[~active, j], clean[~active, j])


def test_coordinated_spoof_attacked_links_agree_with_one_position() -> None:
    # Seen only through the attacked links, the fake position explains every range exactly.
    engine = _spoof_engine((0.2, 0.1, 0.0))
    truth = np.array([[2.5, 2.5, -2.5]] * 2)
    ids = [11, 14]
    clean = np.array([[np.linalg.norm(truth[0] - ANCHOR_POS[i]) for i in ids]] * 2)
    out = engine.apply_array(np.array([0.0, 6.0]), clean, ids, position_ned_m=truth)
    fake = truth[1] + np.array([0.2, 0.1, 0.0]) * 5.0
    residual = out[1] - np.array([np.linalg.norm(fake - ANCHOR_POS[i]) for i in ids])
    assert np.max(np.abs(residual)) < 1e-9
    assert np.max(np.abs(out[1] - clean[1])) > 0.1  # and the attack is real


def test_coordinated_spoof_live_uses_the_latest_local_position() -> None:
    engine = _spoof_engine((0.0, 0.5, 0.0))
    assert 32 in engine.message_ids and 132 in engine.message_ids
    # No position seen yet: ranges pass unchanged.
    assert attacked_cm(engine, 2.0, 11, 300) == 300
    pos = {"time_boot_ms": 0, "x": 2.0, "y": 3.0, "z": -2.5, "vx": 0.0, "vy": 0.0, "vz": 0.0}
    assert send(engine, 2.5, pos, msgid=LOCAL_POSITION_NED).untouched
    got = attacked_cm(engine, 3.0, 11, 300)
    fake = np.array([2.0, 3.0 + 0.5 * 2.0, -2.5])
    assert got == round(float(np.linalg.norm(fake - ANCHOR_POS[11])) * 100)
    assert attacked_cm(engine, 3.0, 12, 300) == 300  # a clean link stays clean


def test_coordinated_spoof_offline_needs_the_truth() -> None:
    engine = _spoof_engine((0.1, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"rules\[0\].*position_ned_m"):
        engine.apply_array(np.zeros(2), np.ones((2, 1)), [11])
    # A stream the rule does not target does not need it.
    np.testing.assert_array_equal(engine.apply_array(np.zeros(2), np.ones((2, 1)), [12]), np.ones((2, 1)))


def test_garbage_frame_scope_randomises_every_field_but_keeps_id_and_time() -> None:
    engine = started(make_profile(rule("garbage", sensor_id=3, scope="frame")))
    action = send(engine, 0.0, distance(3, 250, time_boot_ms=1234))
    assert action.rules == (0,)
    assert action.fields is not None
    assert {"current_distance", "min_distance", "max_distance", "signal_quality"} <= set(action.fields)
    assert "id" not in action.fields and "time_boot_ms" not in action.fields


def test_freeze_state_is_per_vehicle() -> None:
    engine = started(make_profile(rule("freeze", start_s=1.0)))
    send(engine, 0.0, distance(0, 100), sysid=1)
    send(engine, 0.0, distance(0, 700), sysid=2)
    assert send(engine, 2.0, distance(0, 111), sysid=1).fields == {"current_distance": 100}
    assert send(engine, 2.0, distance(0, 777), sysid=2).fields == {"current_distance": 700}


def test_delay_offline_keeps_one_history_per_sensor() -> None:
    engine = started(make_profile(rule("delay", sensor_id=None, delay_s=1.0)))
    t = np.arange(4.0)
    z = np.column_stack([np.arange(4.0), 10 + np.arange(4.0)])
    z[1, 1] = np.nan  # a missing sample is not part of the stream
    out = engine.apply_array(t, z, [0, 1])
    np.testing.assert_allclose(out[:, 0], [np.nan, 0.0, 1.0, 2.0])
    np.testing.assert_allclose(out[:, 1], [np.nan, np.nan, 10.0, 12.0])

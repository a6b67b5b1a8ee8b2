"""The study file: validation with one clear line, grid expansion, stable cell keys, detection figures."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evaluation.trial import EstimatorTrace, TrialResult
from secuav_common.loading import InputError
from study.cli import main
from study.metrics import detection_figures
from study.provenance import code_key
from study.runner import plan
from study.spec import Variant, _grid, expand, parse_study

BASE = """
name: t
scenario: anchors8
duration_s: 5
estimators: [ekf, secekf]
seeds: 3
attacks:
  - none
  - profile: anchors-constant
    params: {offset_m: [0.1, 0.3, 1.0], links: [11, 14]}
"""


def _cells(text: str) -> list:
    return expand(parse_study(text, "s.yaml"), "s.yaml")


def test_grid_counts_and_list_valued_parameters() -> None:
    cells = _cells(BASE)
    assert len(cells) == (1 + 3) * 3  # (none + three offsets) x three seeds
    attacked = [c for c in cells if c.attack == "anchors-constant"]
    assert {c.params["offset_m"] for c in attacked} == {0.1, 0.3, 1.0}
    assert all(c.params["links"] == [11, 14] for c in attacked)  # a flat list of a list parameter is fixed
    swept = _cells(BASE.replace("links: [11, 14]", "links: [[11, 14], [12, 15]]"))
    assert len(swept) == (1 + 3 * 2) * 3


def test_cell_keys_are_stable_and_ignore_the_estimator_list() -> None:
    a = [c.key for c in _cells(BASE)]
    b = [c.key for c in _cells(BASE.replace("[ekf, secekf]", "[ekf, secekf, rarse]"))]
    assert a == b and len(set(a)) == len(a)
    more_seeds = _cells(BASE.replace("seeds: 3", "seeds: 4"))
    assert set(a) < {c.key for c in more_seeds}
    changed = _cells(BASE.replace("duration_s: 5", "duration_s: 6"))
    assert not set(a) & {c.key for c in changed}


def test_plan_runs_only_missing_estimators() -> None:
    cells = _cells(BASE)
    ekf, secekf = Variant("ekf", "ekf", {}), Variant("secekf", "secekf", {})
    key = {n: {c.key: code_key(n, c.profile) for c in cells[:2]} for n in ("ekf", "secekf")}
    done = {(cells[0].key, "ekf"): key["ekf"][cells[0].key], (cells[0].key, "secekf"): key["secekf"][cells[0].key],
            (cells[1].key, "ekf"): key["ekf"][cells[1].key]}  # fmt: skip
    todo, changed = plan(cells, [ekf, secekf], done)
    assert len(todo) == len(cells) - 1 and changed == 0
    assert todo[0] == (cells[1], [secekf])


def test_plan_runs_again_a_row_whose_code_changed() -> None:
    cells = _cells(BASE)[:2]
    ekf = Variant("ekf", "ekf", {})
    done = {(cells[0].key, "ekf"): code_key("ekf", cells[0].profile), (cells[1].key, "ekf"): "computed-by-old-code"}
    todo, changed = plan(cells, [ekf], done)
    assert todo == [(cells[1], [ekf])] and changed == 1


def test_positions_move_start_and_hold_target() -> None:
    cells = _cells(BASE + "positions: [[2.5, 2.5], [0.6, 2.5]]\n")
    assert len(cells) == 2 * 12
    edge = next(c for c in cells if c.position == (0.6, 2.5))
    first = edge.scenario.vehicles[0]
    assert first.start.pos_ned_m[:2] == (0.6, 2.5) and first.target.pos_ned_m[:2] == (0.6, 2.5)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (("[ekf, secekf]", "[ekf, nosuch]"), "estimators"),
        (("offset_m: [0.1, 0.3, 1.0]", "offset_m: [0.1, []]"), "attacks[1]"),
        (("anchors-constant", "no-such-profile"), "attacks[1]"),
        (("scenario: anchors8", "scenario: nowhere"), "scenario"),
        (("seeds: 3", "seeds: 0"), "seeds"),
        (("offset_m: [0.1, 0.3, 1.0]", "offset_m: [0.1, 0.1]"), "attacks[1].params"),
        (("duration_s: 5", "duration_s: -1"), "duration_s"),
        (("name: t", "name: t\nbogus: 1"), "bogus"),
    ],
)
def test_bad_study_file_one_line_naming_file_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: tuple[str, str], field: str
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(BASE.replace(*change))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and field in err, err
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_closed_loop_refuses_what_a_demo_cannot_fly() -> None:
    text = BASE.replace("name: t", "name: t\nmode: closed-loop")
    with pytest.raises(InputError, match="positions"):
        _cells(text + "positions: [[1.0, 1.0]]\n")
    odd = text.replace("[ekf, secekf]", "[off, secekf]")  # YAML's bare `off` is the secure stage off
    assert parse_study(odd, "s.yaml").estimators == ["off", "secekf"]
    with pytest.raises(InputError, match=r"estimators: .off. is for closed-loop"):
        parse_study(BASE.replace("[ekf, secekf]", "[off]"), "s.yaml")


@settings(max_examples=60, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["a", "b", "c", "d"]),
        st.one_of(st.floats(-5, 5), st.lists(st.integers(0, 9), min_size=1, max_size=4, unique=True)),
        max_size=4,
    )
)
def test_grid_is_the_product_of_its_axes(params: dict) -> None:
    combos = _grid(params, set())
    expected = math.prod(len(v) if isinstance(v, list) else 1 for v in params.values())
    assert len(combos) == expected
    assert len({tuple(sorted(c.items())) for c in combos}) == expected
    for combo in combos:
        for k, v in params.items():
            assert combo[k] in v if isinstance(v, list) else combo[k] == v


def _trial(offsets: np.ndarray, named: np.ndarray, has_estimate: np.ndarray) -> TrialResult:
    n, p = offsets.shape
    t = np.arange(1, n + 1) * 0.1
    est = np.where(has_estimate[:, None], 0.0, np.nan) * np.ones((n, 2))
    trace = EstimatorTrace(np.zeros(n), None, est, np.zeros(n), named, named.any(axis=1))
    return TrialResult(t, np.zeros((n, 2)), np.zeros((p, 2)), offsets, np.full(p, 0.1), tuple(range(p)), {"x": trace})


def test_detection_delay_and_false_alarms_from_known_offsets() -> None:
    n, p = 60, 4
    offsets = np.zeros((n, p))
    offsets[30:, 1] = 0.05  # a half-sigma attack from t = 3.1 s
    named = np.zeros((n, p), dtype=bool)
    named[20, 3] = True  # a false alarm before the attack
    named[35:, 1] = True  # caught 0.5 s after onset
    named[40, 2] = True  # a wrong name during the attack
    fig = detection_figures(_trial(offsets, named, np.ones(n, dtype=bool)), "x", attributed=True)
    assert fig["attribution_detection_delay_s"] == pytest.approx(0.5)
    scored = n - 10  # after the 1 s warm-up
    assert fig["attribution_false_naming"] == pytest.approx(2 / scored)
    assert fig["attribution_recall"] == pytest.approx(25 / 30)
    assert fig["attribution_precision"] == pytest.approx(25 / 27)
    by_sigma = fig["attribution_recall_by_sigma"]
    assert by_sigma["0-1"] == pytest.approx(25 / 30) and by_sigma[">10"] is None
    assert fig["own_recall"] is None  # this trace makes no claim of its own (own_named None)
    clean = detection_figures(_trial(np.zeros((n, p)), named, np.ones(n, dtype=bool)), "x", attributed=True)
    assert clean["attribution_detection_delay_s"] is None and clean["attribution_recall"] is None
    assert clean["attribution_false_naming"] == pytest.approx(26 / scored)
    # The same names as the method's own claim: the same definition, under own_*, and no attribution figures.
    own = detection_figures(_trial_own(offsets, named), "x")
    assert own["own_recall"] == fig["attribution_recall"] and own["own_false_naming"] == fig["attribution_false_naming"]
    assert own["own_detection_delay_s"] == pytest.approx(0.5) and own["attribution_recall"] is None


def _trial_own(offsets: np.ndarray, named: np.ndarray) -> TrialResult:
    n = offsets.shape[0]
    trial = _trial(offsets, named, np.ones(n, dtype=bool))
    trace = trial.traces["x"]
    own = EstimatorTrace(trace.err_m, None, trace.est_xy_m, trace.step_time_s, named, named.any(axis=1),
                         own_named=named, own_alarm=named.any(axis=1))  # fmt: skip
    return TrialResult(trial.t_s, trial.truth_xy_m, trial.anchors_xy_m, offsets, trial.sigma_m, trial.sensor_ids,
                       {"x": own})  # fmt: skip


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[2] / "studies").glob("*.yaml")))
def test_bundled_studies_validate(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate", str(path)]) == 0
    assert f"{path}: ok;" in capsys.readouterr().out


def test_estimator_params_are_a_grid_axis_and_part_of_the_cell_key() -> None:
    tuned = _cells(BASE + "estimator_params: {alpha: [0.001, 0.05]}\n")
    plain = _cells(BASE)
    assert len(tuned) == 2 * len(plain)
    assert sorted({c.estimator_params["alpha"] for c in tuned}) == [0.001, 0.05]
    assert not {c.key for c in plain} & {c.key for c in tuned}
    # A fixed value is one grid point; the default (no estimator_params) keeps the keys it always had.
    assert len(_cells(BASE + "estimator_params: {alpha: 0.02}\n")) == len(plain)


def test_bad_estimator_params_and_dims_name_the_field() -> None:
    with pytest.raises(InputError) as err:
        _cells(BASE + "estimator_params: {alpha: [0.01, 1.5]}\n")
    assert "estimator_params" in str(err.value) and "1.5" in str(err.value)
    with pytest.raises(InputError) as err:
        _cells(BASE + "estimator_params: {window_len: 3}\n")
    assert "window_len" in str(err.value)
    # poly runs on the seed's 2-D model only: with dims 3 (the default) the study file is refused.
    two_d = BASE.replace("[ekf, secekf]", "[ekf, poly]")
    with pytest.raises(InputError) as err:
        _cells(two_d)
    assert "estimators[1]" in str(err.value) and "poly" in str(err.value)
    cells = _cells(two_d + "dims: 2\n")
    assert all(c.dims == 2 for c in cells) and not {c.key for c in cells} & {c.key for c in _cells(BASE)}


def test_a_cell_runs_its_estimators_with_the_grid_point() -> None:
    from study.cells import run_cell

    text = BASE.replace("duration_s: 5", "duration_s: 30").replace("seeds: 3", "seeds: 1")
    cells = [c for c in _cells(text + "estimator_params: {alpha: [0.001, 0.3]}\n") if c.attack == "none"]
    rows = {c.estimator_params["alpha"]: run_cell(c, ["secekf"])[1] for c in cells}
    assert all(r["status"] == "ok" and r["estimator"] == "secekf+attribution" for r in rows.values())
    assert rows[0.3]["estimator_params"] == '{"alpha":0.3}'
    # Naming readings is a test at level alpha: a loose alpha names honest readings, a strict one hardly ever.
    assert rows[0.3]["attribution_false_naming"] > rows[0.001]["attribution_false_naming"] + 0.05


def test_an_estimators_own_params_are_a_grid_for_it_alone() -> None:
    text = BASE.replace("estimators: [ekf, secekf]", "estimators: [ekf, {name: secekf, params: {window: [5, 10]}}]")
    study = parse_study(text, "s.yaml")
    # ls: the undefended least-squares baseline every offline study runs, appended where not listed.
    # A secure method's every point twice: its own output, then with the shared attribution.
    assert [v.label for v in study.variants()] == ["ekf", "secekf[window=5]", "secekf[window=5]+attribution",
                                                   "secekf[window=10]", "secekf[window=10]+attribution", "ls"]
    assert [v.attribution for v in study.variants()][1:3] == [False, True]
    with pytest.raises(ValueError, match="attribution is not a parameter"):
        parse_study(text.replace("window: [5, 10]", "attribution: [true, false]"), "s.yaml").variants()
    assert len(expand(study, "s.yaml")) == len(_cells(BASE))  # the same cells: the grid is per estimator
    with pytest.raises(InputError, match=r"estimators\[1\]\.params.*tuning_budget 1"):
        expand(parse_study(text + "tuning_budget: 1\n", "s.yaml"), "s.yaml")
    with pytest.raises(InputError, match="window"):
        expand(parse_study(text.replace("window: [5, 10]", "windoww: 5"), "s.yaml"), "s.yaml")
def test_validate_refuses_more_liars_than_the_layout_supports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 26: four collinear anchors of eight support s = 1, not the 2 that counting sensors gives."""
    studies = Path(__file__).resolve().parents[2] / "studies"
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "collinear4.yaml").write_text((studies / "scenarios" / "collinear4.yaml").read_text())
    text = (studies / "geometry-collinear.yaml").read_text()
    path = tmp_path / "refused.yaml"
    path.write_text(text.replace("estimators: [", "estimator_params: {s: 2}\nestimators: ["))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "s=2 exceeds" in err and "can correct, 1:" in err and "10, 11, 12, 13" in err


def test_noise_scales_are_a_grid_axis_that_leaves_the_stated_keys_alone() -> None:
    plain = _cells(BASE)
    mixed = _cells(BASE + "noise_scales: [1.0, 1.5]\n")
    assert len(mixed) == 2 * len(plain)
    assert {c.key for c in mixed if c.noise_scale == 1.0} == {c.key for c in plain}  # older rows still count
    assert not {c.key for c in mixed if c.noise_scale == 1.5} & {c.key for c in plain}
    for bad, field in (("noise_scales: [0]", "noise_scales"), ("noise_scales: [1.2, 1.2]", "without repeats")):
        with pytest.raises(InputError, match=field):
            parse_study(BASE + bad + "\n", "s.yaml")
    closed = "name: c\nmode: closed-loop\nscenario: wall_hover\nestimators: [secekf]\nseeds: 1\nattacks: [none]\n"
    with pytest.raises(InputError, match="noise_scales: only offline"):
        parse_study(closed + "noise_scales: [1.5]\n", "s.yaml")


def test_a_noisier_flight_than_stated_names_honest_readings_more_often() -> None:
    """The flight's ranges are 1.5x noisier than the scenario says, the estimators are told the scenario's
    sigma: the plain EKF is that much less accurate and SecEKF names honest readings more often."""
    from study.cells import run_cell

    text = BASE.replace("duration_s: 5", "duration_s: 30").replace("seeds: 3", "seeds: [7]")
    cells = [c for c in _cells(text + "noise_scales: [1.0, 1.5]\n") if c.attack == "none"]
    rows = {c.noise_scale: run_cell(c, ["ekf", "secekf"]) for c in cells}
    assert all(r["status"] == "ok" for rs in rows.values() for r in rs)
    assert {r["noise_scale"] for rs in rows.values() for r in rs} == {1.0, 1.5}
    ekf = {k: next(r for r in rs if r["estimator"] == "ekf") for k, rs in rows.items()}
    sec = {k: next(r for r in rs if r["estimator"] == "secekf+attribution") for k, rs in rows.items()}
    assert ekf[1.5]["rmse_m"] > 1.2 * ekf[1.0]["rmse_m"]  # the flight really was noisier
    assert sec[1.5]["attribution_false_naming"] > sec[1.0]["attribution_false_naming"] + 0.01


def test_rows_written_before_noise_scales_existed_read_as_stated_noise(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from study.store import SCHEMA, load, results_dir

    old = pa.schema([f for f in SCHEMA if f.name != "noise_scale"])
    results_dir(tmp_path).mkdir(parents=True)
    row = {"cell": "c1", "estimator": "ekf", "status": "ok", "rmse_m": 0.1}
    pq.write_table(pa.Table.from_pylist([{c: row.get(c) for c in old.names}], schema=old),
                   results_dir(tmp_path) / "part-old.parquet")  # fmt: skip
    frame = load(tmp_path)
    assert frame["noise_scale"].tolist() == [1.0] and frame["rmse_m"].tolist() == [0.1]

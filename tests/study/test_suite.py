"""``secuav-study suite``: the versioned suite's files, a quick study of it with a plugin method added, the
leaderboard and the expected bands; and detection reported two ways (the method's own, the attribution's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from study import store
from study.suite import run as suite
from tests.conftest import free_port_block

STUDY = Path(sys.executable).parent / "secuav-study"


def _run(*args: str, timeout: float = 600.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(STUDY), *args], capture_output=True, text=True, timeout=timeout, check=False)


def test_every_suite_study_validates_in_both_variants() -> None:
    done = _run("suite", "list")
    assert done.returncode == 0, done.stderr
    head, entries = suite.manifest("v1")
    assert head["version"] == 1 and len(entries) == 6
    for entry in entries:
        assert Path(entry.file).stem in done.stdout


def test_expected_bands_name_built_ins_of_the_quick_suite_only() -> None:
    import yaml

    doc = yaml.safe_load((suite.SUITES / "v1" / "expected-quick.yaml").read_text())
    _, entries = suite.manifest("v1")
    stems = {Path(e.file).stem for e in entries if e.quick is not None}
    assert set(doc["bands"]) <= stems
    for bands in doc["bands"].values():
        for name, (lo, hi) in bands.items():
            assert "[" not in name and ":" not in name and 0 <= lo <= hi  # built-ins at their defaults


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_quick_suite_study_with_a_plugin_added_and_its_leaderboard(tmp_path: Path) -> None:
    out = tmp_path / "suite"
    base = free_port_block(5)  # the cluster's ports: scheduler, its HTTP, the worker's nanny, itself, its HTTP
    done = _run("suite", "run", "--quick", "--out", str(out), "--only", "beyond-tolerance", "--add", "huber",
                "--workers", "1", "--ports", str(base), "--no-progress")  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert set(store.load(str(out / "beyond-tolerance"))["worker"]) == {f"tcp://127.0.0.1:{base + 3}"}
    check = _run("suite", "check", str(out))
    board = pd.read_csv(out / "leaderboard.csv")
    assert set(board["study"]) == {"beyond-tolerance"}
    huber = board[board["method"] == "huber"].iloc[0]
    assert huber["origin"] == "secuav-example-plugin 0.1.0" and huber["n"] == 6
    builtin = board[board["method"] != "huber"]
    assert builtin["check"].isin(["in band", "OUT"]).all()  # every built-in has a measured band
    assert check.returncode == (1 if (builtin["check"] == "OUT").any() else 0), check.stdout
    text = (out / "leaderboard.md").read_text()
    assert "clean RMSE / LS" in text and {"clean_vs_ls", "worse_than_ls"} <= set(board.columns)
    assert text.startswith("# SecUAV suite v1 (quick)") and "computed by: secuav " in text and "numpy" in text
    from estimators import registry

    assert f"plugin estimator huber from secuav-example-plugin 0.1.0, code {registry.code_hash('huber')}" in text
    assert json.loads((out / "suite.json").read_text())["added"] == ["huber"]


def test_detection_two_ways_the_methods_own_and_the_attribution(tmp_path: Path) -> None:
    from attack_profiles import library
    from evaluation.trial import run_trial
    from secuav_common.scenario import load_scenario
    from study.metrics import trial_rows

    trial = run_trial(load_scenario("anchors8"), library.load("type-a", offset_m=1.0), ["ekf", "secekf", "huber"],
                      0, 6.0, "hover")  # fmt: skip
    rows = trial_rows(trial)
    for undefended in ("ekf", "huber"):  # they claim nothing: absent, not zero
        assert rows[undefended]["own_recall_all"] is None and rows[undefended]["own_alarm_fraction"] is None
    sec = rows["secekf"]
    assert sec["recall_all"] > 0.9  # the shared attribution names the two attacked links on its output
    assert sec["own_recall_all"] == 0.0 and sec["own_alarm_fraction"] is not None  # it names none itself

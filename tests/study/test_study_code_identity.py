"""Code identity where the code runs: long-lived plain ``dask worker`` processes, a plugin edited between runs.

A worker keeps the modules it imported. Each task carries the client's code hashes; a worker whose loaded code
differs runs the cell in a new process that loads the code on disk (study/fresh.py), and refuses it with one
line when the code on its disk is not the client's either. The plugin here is a real distribution on the
workers' PYTHONPATH (a dist-info folder with its entry point), found by its entry point like an installed one.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from distributed import Client

from study import provenance
from tests.support.clusters import plain_cluster

BIN = Path(sys.executable).parent

MINE = '''"""mine: the example plugin's Huber estimator with a default under edit."""
from secuav_example_plugin.huber import Huber


class Mine(Huber):
    name = "mine"

    def __init__(self, model, *, huber_k: float = {k}, **params):
        super().__init__(model, huber_k=huber_k, **params)
'''

STUDY = """
name: identity
scenario: anchors6_small
duration_s: 6
legs: [moving]
estimators: [mine]
seeds: 2
attacks:
  - none
  - profile: anchors-moving-bias
"""


def _plugin(site: Path, huber_k: str) -> None:
    """The distribution ``idplug`` 0.1.0 in ``site``: package, metadata and its ``secuav.estimators`` entry point."""
    (site / "idplug").mkdir(parents=True, exist_ok=True)
    (site / "idplug" / "__init__.py").write_text("")
    (site / "idplug" / "mine.py").write_text(MINE.replace("{k}", huber_k))
    info = site / "idplug-0.1.0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: idplug\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text("[secuav.estimators]\nmine = idplug.mine:Mine\n")
    (info / "top_level.txt").write_text("idplug\n")


def _study(*args: str, env: dict[str, str]) -> tuple[subprocess.CompletedProcess[str], dict]:
    done = subprocess.run([str(BIN / "secuav-study"), "run", *args, "--no-progress"], capture_output=True, text=True,
                          timeout=400, check=False, env=env)  # fmt: skip
    lines = done.stdout.strip().splitlines()
    return done, json.loads(lines[-1]) if lines else {}


def _mine(out: Path) -> pd.DataFrame:
    from study.store import load

    rows = load(out)
    return rows[rows["estimator"] == "mine"].set_index("cell").sort_index()


FIGURES = ["rmse_m", "mean_error_m", "max_error_m", "valid_fraction", "estimate_fraction"]


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_an_edited_plugin_on_long_lived_workers_gives_a_fresh_clusters_rows_stamped_once(tmp_path: Path) -> None:
    site = tmp_path / "site"
    _plugin(site, "1.345")
    env = {**os.environ, "PYTHONPATH": str(site), "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    study = tmp_path / "identity.yaml"
    study.write_text(STUDY)
    out = tmp_path / "out"
    with plain_cluster(env) as (address, workers):
        first, summary = _study(str(study), "--out", str(out), "--scheduler", address, env=env)
        assert first.returncode == 0 and summary["ran"] == 4 and summary["fresh"] == 0, first.stderr
        before = _mine(out)
        assert (before["status"] == "ok").all(), before["error"].tolist()

        with Client(address, timeout="60s") as client:  # every worker holds the old module, whichever ran cells
            held = client.run(provenance.estimator, "mine")  # import it and hash it, as a cell's rows do
        assert len(held) == 2 and {h["estimator_code"] for h in held.values()} == set(before["estimator_code"])

        _plugin(site, "0.6")  # one line of the estimator changes; the workers keep the module they imported
        second, summary = _study(str(study), "--out", str(out), "--scheduler", address, env=env)
        assert second.returncode == 0, second.stderr
        assert summary["changed"] == 4 and summary["ran"] == 4 and summary["fresh"] == 4, second.stderr
        assert "4 cells re-run because their code changed" in second.stderr
        assert "ran in a new process because their worker had loaded other code" in second.stderr
        after = _mine(out)
        assert set(after["worker"]) <= set(workers)

        third, summary = _study(str(study), "--out", str(out), "--scheduler", address, env=env)
        assert third.returncode == 0 and summary["changed"] == 0 and summary["skipped"] == 4, third.stderr  # once

        # A client whose code is on no worker's disk: every cell refused with one line naming the difference.
        other_site = tmp_path / "other-site"
        _plugin(other_site, "2.0")
        other_env = {**env, "PYTHONPATH": str(other_site)}
        refused, summary = _study(str(study), "--out", str(tmp_path / "other"), "--scheduler", address, env=other_env)
        assert refused.returncode == 1 and summary["failed"] == 4, refused.stderr
        errors = _mine(tmp_path / "other")["error"]
        assert errors.str.startswith("code differs from the client's on this machine: mine ").all(), errors.tolist()
        assert all("\n" not in e for e in errors)

    fresh = tmp_path / "fresh"  # a new cluster that never saw the old code
    reference, summary = _study(str(study), "--out", str(fresh), "--workers", "1", env=env)
    assert reference.returncode == 0 and summary["ran"] == 4, reference.stderr
    ref = _mine(fresh)
    assert (after["status"] == "ok").all(), after["error"].tolist()
    assert list(after.index) == list(ref.index)
    pd.testing.assert_frame_equal(after[FIGURES], ref[FIGURES])  # row for row, exactly
    assert (after["estimator_code"] == ref["estimator_code"]).all() and (after["code_key"] == ref["code_key"]).all()
    assert after["estimator_code"].nunique() == 1 and (after["estimator_code"] != before["estimator_code"]).all()
    assert (after["rmse_m"] != before["rmse_m"]).any()  # the edit changed the numbers, so the check above can fail


def test_identity_names_each_difference_and_gives_the_rows_code_key() -> None:
    from attack_profiles.resolve import resolve_profile
    from study import provenance

    profile = resolve_profile("anchors-moving-bias")
    here = provenance.identity(["ekf", "secekf", "off"], profile)
    assert set(here["estimators"]) == {"ekf", "secekf"} and here["secuav"]
    assert provenance.key_of("ekf", here) == provenance.code_key("ekf", profile)
    assert provenance.differences(here, here) == []
    other = {**here, "estimators": {**here["estimators"], "ekf": "0123456789abcdef"}, "attack": "x"}
    diffs = provenance.differences(here, other)
    assert diffs == [f"ekf {here['estimators']['ekf']} here, 0123456789abcdef expected",
                     f"attack code {here['attack'] or '-'} here, x expected"]  # fmt: skip
    gone = provenance.identity(["no_such_estimator"], None)["estimators"]["no_such_estimator"]
    assert gone.startswith("unavailable (ValueError: unknown estimator 'no_such_estimator'")

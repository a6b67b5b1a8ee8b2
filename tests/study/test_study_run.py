"""``secuav-study run`` as a user runs it: real Dask (a LocalCluster, or a scheduler and workers started
as processes on 127.0.0.1), a run killed half-way and resumed, and one closed-loop cell that flies."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from tests.conftest import free_tcp_port
from tests.support.clusters import dask_cluster  # noqa: F401  (the fixture: a real scheduler + 2 workers)

BIN = Path(sys.executable).parent
STUDY = BIN / "secuav-study"

SMALL = """
name: small
scenario: anchors8
duration_s: 6
estimators: [ls, ekf, secekf]
seeds: 2
attacks:
  - none
  - profile: anchors-constant
    params: {offset_m: 1.5, start_s: 2.0}
"""


def _study(tmp: Path, text: str, name: str = "study.yaml") -> Path:
    path = tmp / name
    path.write_text(text)
    return path


def _run(*args: str, timeout: float = 240.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(STUDY), *args], capture_output=True, text=True, timeout=timeout, check=False)


def _summary(done: subprocess.CompletedProcess[str]) -> dict:
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_small_study_on_a_local_cluster_writes_rows_report_and_figures(tmp_path: Path) -> None:
    out = tmp_path / "out"
    done = _run("run", str(_study(tmp_path, SMALL)), "--out", str(out), "--workers", "2", "--no-progress")
    assert done.returncode == 0, done.stderr
    assert _summary(done) == {"cells": 4, "ran": 4, "skipped": 0, "failed": 0, "changed": 0, "fresh": 0,
                             "out": str(out)}  # fmt: skip
    rows = pd.read_parquet(out / "results.parquet")
    # The secure method twice: its own output and its output with the shared attribution.
    assert len(rows) == 16 and set(rows["estimator"]) == {"ls", "ekf", "secekf", "secekf+attribution"}
    assert (rows["status"] == "ok").all()
    assert dict(zip(rows["estimator"], rows["output"], strict=True))["secekf+attribution"] == "attributed"
    for column in ("cell", "params", "seed", "rmse_m", "p95_error_m", "max_error_m", "estimate_fraction",
                   "own_recall", "own_precision", "own_false_naming", "attribution_recall", "attribution_precision",
                   "attribution_false_naming", "attribution_detection_delay_s", "step_time_us_median", "worker",
                   "started_at", "wall_s"):  # fmt: skip
        assert column in rows.columns
    assert rows["worker"].str.startswith("tcp://127.0.0.1:").all()
    attacked = rows[rows["attack"] == "anchors-constant"].set_index("estimator")
    # The secure estimator catches a 15-sigma bias and stays accurate; the plain EKF is dragged off.
    assert (attacked.loc["secekf", "rmse_m"] < 0.15).all() and (attacked.loc["ekf", "rmse_m"] > 0.25).all()
    delay = attacked["attribution_detection_delay_s"]
    assert delay.loc["secekf+attribution"].notna().all() and delay.loc["ekf"].isna().all()
    assert attacked["own_recall"].loc["secekf"].eq(0).all()  # SecEKF names nobody itself: the attribution does
    report = (out / "report.md").read_text()
    assert "Clean runs: false alarms" in report and "anchors-constant" in report
    assert "## Summary: error and time per step, per attack and estimator" in report and "Table 5" not in report
    again = _run("run", str(out / ".." / "study.yaml"), "--out", str(out), "--no-progress")
    assert again.returncode == 0 and _summary(again)["skipped"] == 4 and _summary(again)["ran"] == 0
    assert len(pd.read_parquet(out / "results.parquet")) == 16


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_run_killed_half_way_resumes_without_duplicates_or_gaps(tmp_path: Path) -> None:
    text = SMALL.replace("seeds: 2", "seeds: 20").replace("offset_m: 1.5", "offset_m: [0.5, 1.5]")
    path = _study(tmp_path, text)
    out = tmp_path / "out"
    proc = subprocess.Popen([str(STUDY), "run", str(path), "--out", str(out), "--workers", "2", "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    parts = out / "results.parquet"
    deadline = time.monotonic() + 120
    while len(list(parts.glob("part-*.parquet"))) < 5:  # some cells are written: now kill it hard
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    before = pd.read_parquet(parts)
    assert 0 < before["cell"].nunique() < 60
    done = _run("run", str(path), "--out", str(out), "--workers", "2", "--no-progress")
    assert done.returncode == 0, done.stderr
    summary = _summary(done)
    assert summary["cells"] == 60 and summary["skipped"] >= before["cell"].nunique()
    assert summary["ran"] + summary["skipped"] == 60
    rows = pd.read_parquet(parts)
    assert len(rows) == 240 and not rows.duplicated(["cell", "estimator"]).any()  # ls, ekf, secekf twice
    kept = rows.merge(before, on=["cell", "estimator"], suffixes=("", "_before"))
    assert len(kept) == len(before) and (kept["rmse_m"] == kept["rmse_m_before"]).all()  # never rewritten


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_real_scheduler_and_workers_run_the_cells_and_are_named_in_the_rows(
    tmp_path: Path, dask_cluster: tuple[str, list[str]]  # noqa: F811  (the fixture imported above)
) -> None:
    address, workers = dask_cluster
    out = tmp_path / "out"
    text = SMALL.replace("seeds: 2", "seeds: 6")
    done = _run("run", str(_study(tmp_path, text)), "--out", str(out), "--scheduler", address, "--no-progress")
    assert done.returncode == 0, done.stderr
    assert _summary(done)["ran"] == 12
    rows = pd.read_parquet(out / "results.parquet")
    assert set(rows["worker"]) <= set(workers) and len(rows) == 48
    assert "workers: " + ", ".join(sorted(set(rows["worker"]))) in (out / "report.md").read_text()


def test_an_unreachable_scheduler_is_one_clear_line(tmp_path: Path) -> None:
    port = free_tcp_port()
    done = _run("run", str(_study(tmp_path, SMALL)), "--out", str(tmp_path / "o"), "--scheduler",
                f"tcp://127.0.0.1:{port}", "--no-progress", timeout=120)  # fmt: skip
    assert done.returncode == 2
    assert f"127.0.0.1:{port}" in done.stderr.strip().splitlines()[-1]


@pytest.mark.xdist_group("flight_stack")
@pytest.mark.slow
def test_one_closed_loop_cell_flies_the_demo_through_the_proxy(tmp_path: Path) -> None:
    text = """
name: flight
mode: closed-loop
scenario: wall_hover
duration_s: 6
settle_s: 2
estimators: [secekf]
seeds: [1]
attacks:
  - profile: wall-spoof-two
    params: {rate_per_s: 0.4}
"""
    out = tmp_path / "out"
    done = _run("run", str(_study(tmp_path, text)), "--out", str(out), "--workers", "1", "--no-progress", timeout=400)
    assert done.returncode == 0, done.stderr + done.stdout
    (row,) = pd.read_parquet(out / "results.parquet").to_dict("records")
    assert row["status"] == "ok" and row["mode"] == "closed-loop" and not row["collided"]
    # Distance to the wall from the simulator's truth, with the two attacked sensors flagged by the proxy.
    assert 0.0 < row["max_error_m"] < 1.5 and row["min_distance_m"] > 1.0
    flagged = json.loads(row["flagged"])
    assert flagged.get("0", 0) > 0.5 and flagged.get("2", 0) > 0.5


def test_a_cell_that_raises_is_recorded_with_its_error_and_the_rest_go_on(tmp_path: Path) -> None:
    from study.runner import dask_client, failed_cells, run
    from study.spec import expand, parse_study

    path = _study(tmp_path, SMALL)
    cells = expand(parse_study(SMALL, str(path)), str(path))
    good = cells[0]
    first = good.scenario.vehicles[0]
    deaf = first.model_copy(update={"sensors": first.sensors.model_copy(update={"uwb": None})})
    # No UWB on the vehicle: the real trial has no anchor ranges to model and raises.
    broken = replace(good, key="0" * 16, scenario=good.scenario.model_copy(update={"vehicles": [deaf]}))
    out = tmp_path / "out"
    with dask_client(1, None) as client:
        summary = run([broken, good], ["ekf"], out, client, set(), progress=False)
    assert summary.ran == 2 and failed_cells(out) == 1
    rows = pd.read_parquet(out / "results.parquet").set_index("cell")
    assert rows.loc[good.key, "status"] == "ok"
    assert rows.loc["0" * 16, "status"] == "error" and rows.loc["0" * 16, "error"]

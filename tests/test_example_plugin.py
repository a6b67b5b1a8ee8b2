"""examples/plugin as a researcher uses it: installed beside secuav as a distribution of its own
(scripts/setup.sh), found by every command by itself, with nothing of it in secuav's tree.

Through the real commands: ``secuav-plugins``, ``secuav-attack``, ``secuav-eval``, ``secuav-study`` on a real
``dask scheduler`` and two ``dask worker`` processes started without ``--preload``, and the live proxy
(``secuav-proxy --secure huber`` with a profile of the plugin's primitive) fed by the simulator over UDP.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pandas as pd
import pytest

from tests.support.clusters import dask_cluster  # noqa: F401  (the fixture: a real scheduler + 2 workers)

BIN = Path(sys.executable).parent
DIST = "secuav-example-plugin"


def _cmd(name: str, *args: str, timeout: float = 240.0, env: dict[str, str] | None = None,
         ) -> subprocess.CompletedProcess[str]:  # fmt: skip
    return subprocess.run([str(BIN / name), *args], capture_output=True, text=True, timeout=timeout, check=False,
                          env=env)  # fmt: skip


def test_the_plugin_is_installed_as_its_own_distribution() -> None:
    from importlib import metadata

    dist = metadata.distribution(DIST)
    groups = {ep.group for ep in dist.entry_points}
    assert groups == {"secuav.estimators", "secuav.primitives", "secuav.profiles", "secuav.scenarios"}
    assert "site-packages" in str(dist.locate_file("secuav_example_plugin"))  # not this tree


def test_the_listing_names_every_part_and_its_distribution() -> None:
    done = _cmd("secuav-plugins", "--json")
    assert done.returncode == 0, done.stderr
    groups = json.loads(done.stdout)["groups"]
    found = {g: {r["name"]: r for r in rows} for g, rows in groups.items()}
    assert found["secuav.estimators"]["huber"]["dist"] == DIST
    assert any(p.startswith("huber_k=1.345 in [0.5, 5]") for p in found["secuav.estimators"]["huber"]["params"])
    assert found["secuav.primitives"]["moving_bias"]["version"] == "0.1.0"
    assert "anchors-moving-bias" in found["secuav.profiles"] and "anchors6_small" in found["secuav.scenarios"]


def test_one_estimator_described_as_help_would() -> None:
    done = _cmd("secuav-plugins", "--estimator", "huber")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("huber: a Huber M-estimator") and f"from {DIST} 0.1.0" in lines[1]
    assert lines[4].split() == ["huber_k", "1.345", "in", "[0.5,", "5]"]  # its own parameters first
    assert ["s", "null"] in [line.split() for line in lines]
    row = json.loads(_cmd("secuav-plugins", "--estimator", "huber", "--json").stdout)
    assert row["parameters"]["n_irls"] == {"default": 8, "low": 1, "high": 50} and row["dist"] == DIST
    unknown = _cmd("secuav-plugins", "--estimator", "hubr")
    assert unknown.returncode == 2 and "unknown estimator 'hubr'" in unknown.stderr and "huber" in unknown.stderr


def test_the_primitive_is_in_validation_schema_and_list() -> None:
    done = _cmd("secuav-attack", "validate", "anchors-moving-bias", "--scenario", "anchors6_small")
    assert done.returncode == 0 and done.stdout.startswith("ok: anchors-moving-bias"), done.stderr
    schema = json.loads(_cmd("secuav-attack", "schema").stdout)
    assert "MovingBiasRule" in schema["$defs"]
    assert f"[from {DIST} 0.1.0]" in _cmd("secuav-attack", "list").stdout


def test_secuav_eval_runs_the_plugin_estimator_on_the_plugin_attack_and_scenario(tmp_path: Path) -> None:
    done = _cmd("secuav-eval", "--scenario", "anchors6_small", "--attack", "anchors-moving-bias", "--leg", "moving",
                "--estimators", "ekf,huber,secuav_example_plugin.huber:Huber", "--trials", "1", "--duration", "8",
                "--out", str(tmp_path))  # fmt: skip
    assert done.returncode == 0, done.stderr
    rows = json.loads((tmp_path / "results.json").read_text())["estimators"]
    assert set(rows) == {"ls", "ekf", "huber", "secuav_example_plugin.huber:Huber"}  # ls: the baseline, always
    assert rows["huber"]["rmse_m"] == rows["secuav_example_plugin.huber:Huber"]["rmse_m"]  # one class, two names


TUNE = """
name: tune
scenario: anchors6_small
duration_s: 6
legs: [moving]
estimators: [ekf, {name: huber, params: {huber_k: [1.0, 1.345]}}]
tuning_budget: 2
seeds: 2
attacks:
  - none
  - profile: anchors-moving-bias
"""


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_study_on_plain_dask_workers_tunes_the_plugin_alone(
    tmp_path: Path,
    dask_cluster: tuple[str, list[str]],  # noqa: F811
) -> None:
    address, workers = dask_cluster
    study = tmp_path / "tune.yaml"
    study.write_text(TUNE)
    out = tmp_path / "out"
    done = _cmd("secuav-study", "run", str(study), "--out", str(out), "--scheduler", address, "--no-progress")
    assert done.returncode == 0, done.stderr
    rows = pd.read_parquet(out / "results.parquet")
    assert (rows["status"] == "ok").all(), rows["error"].dropna().tolist()
    assert set(rows["worker"]) <= set(workers)
    assert sorted(set(rows["estimator"])) == ["ekf", "huber[huber_k=1.0]", "huber[huber_k=1.345]", "ls"]
    huber = rows[rows["estimator_name"] == "huber"]
    assert (huber["estimator_dist"] == DIST).all() and (huber["estimator_version"] == "0.1.0").all()
    attacked = rows[rows["attack"] == "anchors-moving-bias"]
    assert all(json.loads(p)["moving_bias"]["dist"] == DIST for p in attacked["primitives"])
    assert rows["secuav_commit"].notna().all() and rows["numpy_version"].notna().all()


def test_over_the_tuning_budget_is_refused(tmp_path: Path) -> None:
    study = tmp_path / "tune.yaml"
    study.write_text(TUNE.replace("[1.0, 1.345]", "[1.0, 1.2, 1.345]"))
    done = _cmd("secuav-study", "validate", str(study))
    assert done.returncode == 2 and "tuning_budget 2" in done.stderr and "estimators[1]" in done.stderr


MINE = '''"""A researcher's estimator under edit (a module on PYTHONPATH, no entry point)."""
from secuav_example_plugin.huber import Huber


class Mine(Huber):
    name = "mine"

    def __init__(self, model, *, huber_k: float = {k}, **params):
        super().__init__(model, huber_k=huber_k, **params)
'''


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_changed_estimator_code_re_runs_exactly_its_rows(tmp_path: Path) -> None:
    pkg = tmp_path / "lib"
    pkg.mkdir()
    (pkg / "mine_est.py").write_text(MINE.replace("{k}", "1.345"))
    env = {**os.environ, "PYTHONPATH": str(pkg)}
    study = tmp_path / "s.yaml"
    study.write_text(TUNE.replace("{name: huber, params: {huber_k: [1.0, 1.345]}}", "mine_est:Mine"))
    out = tmp_path / "out"
    args = ("run", str(study), "--out", str(out), "--workers", "1", "--no-progress")
    first = _cmd("secuav-study", *args, env=env)
    assert first.returncode == 0, first.stderr
    before = pd.read_parquet(out / "results.parquet")
    again = _cmd("secuav-study", *args, env=env)
    assert json.loads(again.stdout.splitlines()[-1])["skipped"] == 4  # unchanged code: nothing re-runs
    (pkg / "mine_est.py").write_text(MINE.replace("{k}", "2.0"))  # a new default
    third = _cmd("secuav-study", *args, env=env)
    summary = json.loads(third.stdout.splitlines()[-1])
    assert summary["changed"] == 4 and summary["ran"] == 4, third.stderr
    assert "4 cells re-run because their code changed" in third.stderr
    after = pd.read_parquet(out / "results.parquet")
    ekf_then = before[before["estimator"] == "ekf"].set_index("cell")["started_at"]
    ekf_now = after[after["estimator"] == "ekf"].sort_values("started_at").groupby("cell")["started_at"].last()
    assert (ekf_now.sort_index() == ekf_then.sort_index()).all()  # the EKF's rows were not computed again
    mine = after[after["estimator"] == "mine_est:Mine"].sort_values("started_at")
    assert mine["estimator_code"].nunique() == 2 and len(mine) == 8  # old and new rows, the new ones supersede


LIVE_PROFILE = """
name: moving-live
description: the plugin's primitive with a threshold below the hover's own jitter, so it acts live
rules:
  - kind: moving_bias
    target: {message: DISTANCE_SENSOR, sensor_id: [10, 13]}
    offset: 1.5
    min_speed_mps: 0.001
"""


@pytest.fixture
def live_proxy(tmp_path: Path, udp_port: Callable[[], int]) -> Iterator[tuple[subprocess.Popen[bytes], int, Path]]:
    veh, gcs = udp_port(), udp_port()
    profile = tmp_path / "moving-live.yaml"
    profile.write_text(LIVE_PROFILE)
    rec = tmp_path / "rec"
    log = (tmp_path / "proxy.log").open("wb")
    proc = subprocess.Popen([str(BIN / "secuav-proxy"), "--scenario", "anchors6_small", "--profile", str(profile),
                             "--secure", "huber", "--broker", "none", "--vehicle", f"udpin://127.0.0.1:{veh}",
                             "--ground", f"udpout://127.0.0.1:{gcs}", "--record", str(rec), "--stats-interval", "1"],
                            stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        # Ready before the flight starts, however long the start-up takes on a loaded machine: after 10 s it used
        # to fly anyway, into a proxy still importing, and recorded nothing (seen in a parallel run).
        for _ in range(600):
            if "proxy.ready" in (tmp_path / "proxy.log").read_text():
                break
            assert proc.poll() is None, (tmp_path / "proxy.log").read_text()
            asyncio.run(asyncio.sleep(0.1))
        assert "proxy.ready" in (tmp_path / "proxy.log").read_text(), "secuav-proxy not ready within 60 s"
        yield proc, veh, rec
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(15)
        log.close()


@pytest.mark.timeout(90)
def test_the_live_proxy_runs_the_plugin_estimator_and_primitive(
    live_proxy: tuple[subprocess.Popen[bytes], int, Path], tmp_path: Path
) -> None:
    from flightsim.runner import RunConfig, SimRunner
    from secuav_common.scenario import load_scenario
    from secuav_common.urls import Endpoint

    proc, veh, rec = live_proxy

    async def fly() -> None:
        stop = asyncio.Event()
        async with SimRunner(RunConfig(load_scenario("anchors6_small"), [Endpoint("udpout", "127.0.0.1", veh)])) as r:
            task = asyncio.create_task(r.run(stop))
            await asyncio.sleep(4.0)
            stop.set()
            await asyncio.wait_for(task, 5.0)

    asyncio.run(fly())
    proc.send_signal(signal.SIGINT)
    assert proc.wait(15) == 0
    log = (tmp_path / "proxy.log").read_text()
    assert "secure=huber" in log and "profile=moving-live" in log and "skipped" not in log
    notes = [n for frame in json.loads((rec / "v1" / "index.json").read_text()) for n in frame["notes"]]
    assert notes.count("attack:moving-live:rules[0]") > 10, sorted(set(notes))
    assert notes.count("secure:huber") > 10


def test_the_console_offers_the_plugin_profile_and_estimator() -> None:
    import estimators
    from webconsole.api import library_json, profile_request

    entry = next(e for e in library_json() if e["name"] == "anchors-moving-bias")
    assert "moving_bias" in entry["text"]
    assert profile_request({"profile": "anchors-moving-bias"}) == {"library": "anchors-moving-bias", "parameters": {}}
    assert "huber" in estimators.names()  # what GET /api/estimators lists beside "off"


@pytest.mark.xdist_group("flight_stack")
@pytest.mark.slow
def test_a_closed_loop_flight_with_the_plugin_estimator_and_primitive(tmp_path: Path) -> None:
    """secuav-demo starts its own secuav-proxy with --secure huber and the profile: that process finds both."""
    (tmp_path / "wall-moving.yaml").write_text(
        "name: wall-moving\nrules:\n  - kind: moving_bias\n    target: {message: DISTANCE_SENSOR, sensor_id: 0}\n"
        "    offset: 0.3\n    min_speed_mps: 0.001\n"
    )
    study = tmp_path / "flight.yaml"
    study.write_text("name: flight\nmode: closed-loop\nscenario: wall_hover\nduration_s: 6\nsettle_s: 2\n"
                     "estimators: [huber]\nseeds: [1]\nattacks:\n  - profile: wall-moving.yaml\n")  # fmt: skip
    out = tmp_path / "out"
    done = _cmd("secuav-study", "run", str(study), "--out", str(out), "--workers", "1", "--no-progress", timeout=400)
    assert done.returncode == 0, done.stderr + done.stdout
    (row,) = pd.read_parquet(out / "results.parquet").to_dict("records")
    assert row["status"] == "ok" and row["mode"] == "closed-loop" and not row["collided"], row["error"]
    assert row["estimator_dist"] == DIST and json.loads(row["primitives"])["moving_bias"]["dist"] == DIST
    assert row["max_error_m"] < 1.5  # flown on the plugin's estimate, distance to the wall from truth


@pytest.mark.xdist_group("flight_stack")
@pytest.mark.slow
def test_a_closed_loop_study_flies_the_plugins_scenario(tmp_path: Path) -> None:
    """The plugin's anchors6_small (hold (2, 2) among six anchors) has the localise demo's shape: the study's cell
    is a real secuav-demo localise flight of it, scored from the plugin scenario's own hold point."""
    study = tmp_path / "flight.yaml"
    study.write_text("name: plugin-scenario\nmode: closed-loop\nscenario: anchors6_small\nduration_s: 6\n"
                     "settle_s: 2\nestimators: [huber]\nseeds: [1]\nattacks: [none]\n")  # fmt: skip
    out = tmp_path / "out"
    done = _cmd("secuav-study", "run", str(study), "--out", str(out), "--workers", "1", "--no-progress", timeout=400)
    assert done.returncode == 0, done.stderr + done.stdout
    (row,) = pd.read_parquet(out / "results.parquet").to_dict("records")
    assert row["status"] == "ok" and row["mode"] == "closed-loop" and row["scenario"] == "anchors6_small", row["error"]
    assert not row["collided"] and row["estimator_dist"] == DIST
    # the bundled localise demo holds (2.5, 2.5): 0.71 m from this scenario's (2, 2), so this tells which one flew
    assert row["rmse_m"] < 0.35

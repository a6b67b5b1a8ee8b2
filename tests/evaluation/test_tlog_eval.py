"""secuav-eval --tlog on logs recorded from the real simulator over loopback UDP, with and without truth.

The logs come from the real ``secuav-sim`` (anchors8, as fast as possible)
sending to our recorder on 127.0.0.1; one is recorded through the type-A
attack (links 11 and 14 biased from 5 s) while the recorder, as a minimal
ground station, has the vehicle take off (so heights come from the downward
laser); one is clean, of the vehicle parked (no laser reading: heights from
LOCAL_POSITION_NED).
"""

from __future__ import annotations

import asyncio
import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from attack_profiles import Engine, library
from attack_profiles.profile import Profile
from evaluation.cli import main
from evaluation.tlog import _framed, log_streams, read_tlog, read_truth_csv
from mitm_proxy.tools.record import Counts, TlogWriter, record
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint

SIM = str(Path(sys.executable).with_name("secuav-sim"))
DURATION_S = 20
ESTIMATORS = "ekf,secekf,rarse"


async def _record_sim(
    tlog: Path,
    truth: Path,
    profile: Profile | None,
    scenario: str = "anchors8",
    vehicles: int = 1,
    takeoff: bool = False,
) -> Counts:
    """The recorder binds 127.0.0.1 port 0 (a free port, no race) per vehicle; the sim sends there."""
    engine = None if profile is None else Engine(profile, seed=0, scenario=load_scenario(scenario))
    bound: asyncio.Future[list[tuple[str, int]]] = asyncio.get_running_loop().create_future()
    endpoints = [Endpoint("udpin", "127.0.0.1", 0) for _ in range(vehicles)]
    task = asyncio.create_task(
        record(endpoints, tlog, engine, duration_s=60.0, idle_stop_s=1.0, on_bound=bound.set_result, takeoff=takeoff)
    )
    ports = [addr[1] for addr in await asyncio.wait_for(bound, 10)]
    args = [scenario, "--fast", "--duration", str(DURATION_S), "-q", "--truth-csv", str(truth)]
    for port in ports:  # one --mavlink per vehicle
        args += ["--mavlink", f"udpout://127.0.0.1:{port}"]
    proc = await asyncio.create_subprocess_exec(SIM, *args)
    assert await asyncio.wait_for(proc.wait(), 60) == 0
    return await asyncio.wait_for(task, 30)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("tlogs")
    out: dict[str, Path] = {}
    attack = library.load("type-a", start_s=5.0)
    for name, profile in (("attacked", attack), ("clean", None)):
        counts = asyncio.run(_record_sim(root / f"{name}.tlog", root / f"{name}.csv", profile, takeoff=bool(profile)))
        assert counts.frames_in > 3000 and counts.written == counts.frames_in
        assert (counts.rewritten > 200) == (profile is not None)
        out[name] = root / f"{name}.tlog"
        out[f"{name}_truth"] = root / f"{name}.csv"
    return out


def _eval(out: Path, *extra: str) -> int:
    return main(["--scenario", "anchors8", "--estimators", ESTIMATORS, "--out", str(out), *extra])


@pytest.mark.timeout(120)
def test_attacked_log_with_truth_scores_errors_and_names_the_links(logs: dict[str, Path], tmp_path: Path) -> None:
    assert _eval(tmp_path, "--tlog", str(logs["attacked"]), "--truth", str(logs["attacked_truth"])) == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["source"] == "tlog" and res["errors_scored"] and res["detection_scored"]
    assert res["log"]["sysids"] == [1] and abs(res["rate_hz"] - 10.0) < 0.1
    assert res["frames"] >= DURATION_S * 10 - 2
    rows = res["estimators"]
    for name in ("secekf+attribution", "rarse+attribution"):
        row = rows[name]
        assert row["rmse_m"] < 0.15, name
        assert row["attack_detection_recall"] >= 0.9 and row["attack_detection_precision"] >= 0.9, name
        named = row["named_fraction_by_sensor_id"]
        assert named["11"] > 0.6 and named["14"] > 0.6, name  # attacked from 5 s of 20
        # Every other reading, the downward laser (id 0) too: the filters follow the take-off climb.
        assert max(v for k, v in named.items() if k not in ("11", "14")) < 0.05, name
    assert rows["ekf"]["rmse_m"] > 3 * rows["secekf+attribution"]["rmse_m"]  # the undefended filter is dragged
    assert rows["ekf"]["attack_detection_recall"] == 0.0
    for png in ("attack.png", "errors.png", "trajectory.png"):
        assert (tmp_path / png).stat().st_size > 1000


@pytest.mark.timeout(120)
@pytest.mark.timeout(60)
def test_flight_log_heights_come_from_the_downward_laser(logs: dict[str, Path]) -> None:
    vehicle_logs, _ = read_tlog(logs["attacked"])
    streams, _ = log_streams(vehicle_logs, [1], {1: 0}, 10.0, read_truth_csv(logs["attacked_truth"]))
    s = streams[1]
    late = s.t_s > 10.0  # after the climb to MIS_TAKEOFF_ALT (2.5 m)
    assert np.all(np.abs(s.laser_down_m[late] - 2.5) < 0.3)
    assert np.all(np.abs(s.laser_down_m[late] + s.truth_ned_m[late, 2]) < 0.1)  # laser = height from truth
    assert 0 not in s.readings and set(s.readings) == set(range(10, 18))  # the laser (id 0) is not a range


def test_log_without_truth_reports_alarms_links_and_step_times_only(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _eval(tmp_path, "--tlog", str(logs["attacked"])) == 0
    assert "n/a" in capsys.readouterr().out
    res = json.loads((tmp_path / "results.json").read_text())
    assert not res["errors_scored"] and not res["detection_scored"]
    sec = res["estimators"]["secekf+attribution"]
    assert sec["rmse_m"] is None and sec["max_error_m"] is None
    assert sec["attack_detection_recall"] is None and sec["attack_detection_precision"] is None
    assert sec["named_fraction_by_sensor_id"]["11"] > 0.6 and sec["step_time_us_median"] > 0
    # The autopilot's LOCAL_POSITION_NED is reported as a reference, never as truth.
    assert sec["deviation_from_local_position_ned"]["rmse_m"] < 0.3
    assert res["estimators"]["ekf"]["deviation_from_local_position_ned"]["rmse_m"] > 0.2


@pytest.mark.timeout(120)
def test_clean_log_with_an_attack_added_offline(logs: dict[str, Path], tmp_path: Path) -> None:
    args = ("--tlog", str(logs["clean"]), "--attack", "type-a", "--param", "links=[12, 16]", "--param", "offset_m=3")
    assert _eval(tmp_path / "a", *args) == 0
    res = json.loads((tmp_path / "a" / "results.json").read_text())
    assert res["attack"] == "type-a" and not res["errors_scored"] and res["detection_scored"]
    sec = res["estimators"]["secekf+attribution"]
    assert sec["attack_detection_recall"] >= 0.95 and sec["attack_detection_precision"] >= 0.9
    assert sec["named_fraction_by_sensor_id"]["12"] > 0.9
    # Same log, same attack, same numbers.
    assert _eval(tmp_path / "b", *args) == 0
    again = json.loads((tmp_path / "b" / "results.json").read_text())
    named = again["estimators"]["secekf+attribution"]["named_fraction_by_sensor_id"]
    assert named == sec["named_fraction_by_sensor_id"]


@pytest.mark.timeout(60)
def test_clean_log_with_truth_matches_the_noise(logs: dict[str, Path]) -> None:
    """Readings and truth share the boot clock: honest ranges sit within noise of the truth's geometry."""
    vehicle_logs, info = read_tlog(logs["clean"])
    truth = read_truth_csv(logs["clean_truth"])
    t_truth, pos = truth[1]
    anchors = load_scenario("anchors8").anchor_positions()
    resid = []
    for k, a in anchors.items():
        rows = np.array(vehicle_logs[1].readings[10 + k])
        true_pos = np.column_stack([np.interp(rows[:, 0], t_truth, pos[:, c]) for c in range(3)])
        resid.append(rows[:, 1] - np.linalg.norm(true_pos - np.asarray(a), axis=1))
    resid_all = np.concatenate(resid)
    assert info.invalid_readings > 0  # the downward laser on the ground reads "no target": NaN, not 0
    assert abs(float(np.mean(resid_all))) < 0.03 and 0.07 < float(np.std(resid_all)) < 0.13


def _distance_frame(seq: int, sensor_id: int, cm: int, t_ms: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    mav.seq = seq
    msg = mav.distance_sensor_encode(t_ms, 5, 3000, cm, 0, sensor_id, 100, 0, signal_quality=100)
    return bytes(msg.pack(mav))


def test_recorder_rewrites_with_the_original_header_drops_and_delays(tmp_path: Path) -> None:
    profile = library.load("type-a", links=[11], offset_m=2.0)
    out = tmp_path / "w.tlog"
    with out.open("wb") as fh:
        writer = TlogWriter(fh, Engine(profile, seed=0))
        writer.feed(_distance_frame(7, 11, 400, 100))
        writer.feed(_distance_frame(8, 12, 400, 100))
        writer.close()
    data = out.read_bytes()
    parser = mavlink.MAVLink(None)
    frames, pos = [], 0
    while pos < len(data):
        stamp = struct.unpack(">Q", data[pos : pos + 8])[0]
        assert stamp > 1_600_000_000_000_000  # wall-clock microseconds, as QGC writes them
        pos += 8
        length = data[pos + 1] + 12  # MAVLink 2: header 10 + payload + CRC 2, unsigned
        msgs = parser.parse_buffer(data[pos : pos + length])
        pos += length
        frames.extend(msgs or [])
    assert [(m.id, m.current_distance, m.get_seq(), m.get_srcSystem()) for m in frames] == [
        (11, 600, 7, 3),  # +2 m, CRC valid (parsed), same sysid and sequence number
        (12, 400, 8, 3),
    ]
    assert writer.counts.rewritten == 1 and writer.counts.written == 2


def test_recorder_holds_delayed_frames_on_the_vehicle_clock(tmp_path: Path) -> None:
    profile = library.load("distance-delayed", sensors=[11], start_s=0.0, delay_s=0.5)
    with (tmp_path / "d.tlog").open("wb") as fh:
        writer = TlogWriter(fh, Engine(profile))
        writer.feed(_distance_frame(1, 11, 400, 1000))  # held until vehicle time 1.5 s
        writer.feed(_distance_frame(2, 12, 400, 1200))
        assert writer.counts.written == 1
        writer.feed(_distance_frame(3, 12, 400, 1600))
        assert writer.counts.written == 3 and writer.counts.delayed == 1
        writer.close()


def test_framing_takes_the_last_reading_of_each_window() -> None:
    rows = [(0.10, 1.0), (0.15, 2.0), (0.20, 3.0), (0.45, 4.0)]
    framed = _framed(rows, np.array([0.1, 0.2, 0.3, 0.4, 0.5]), 0.1)
    assert framed[:2].tolist() == [1.0, 3.0] and np.isnan(framed[2:4]).all() and framed[4] == 4.0


def test_bad_log_and_truth_files_name_the_problem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    garbage = tmp_path / "garbage.tlog"
    garbage.write_bytes(bytes(range(256)) * 20)
    assert _eval(tmp_path / "o1", "--tlog", str(garbage)) == 2
    assert "garbage.tlog" in capsys.readouterr().err
    assert _eval(tmp_path / "o2", "--tlog", str(tmp_path / "missing.tlog")) == 2
    assert "no such file" in capsys.readouterr().err
    bad_csv = tmp_path / "truth.csv"
    bad_csv.write_text("t_s,sysid,north_m,east_m\n0.1,1,2.5,2.5\n")
    with pytest.raises(InputError, match="down_m"):
        read_truth_csv(bad_csv)
    bad_csv.write_text("t_s,sysid,north_m,east_m,down_m\n0.1,1,2.5,x,0\n")
    with pytest.raises(InputError, match="line 2: east_m"):
        read_truth_csv(bad_csv)
    assert _eval(tmp_path / "o3", "--truth", str(bad_csv), "--attack", "none") == 2
    assert "only with --tlog" in capsys.readouterr().err
    assert not any((tmp_path / o).exists() for o in ("o1", "o2", "o3"))


@pytest.mark.timeout(60)
def test_log_of_another_vehicle_is_refused(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _eval(tmp_path / "o", "--tlog", str(logs["clean"]), "--scenario", "formation") == 2
    err = capsys.readouterr().err
    assert "sysid 2" in err and not (tmp_path / "o").exists()


@pytest.mark.timeout(120)
def test_two_vehicles_on_two_ports_score_the_inter_vehicle_range(tmp_path: Path) -> None:
    tlog, truth = tmp_path / "f.tlog", tmp_path / "f.csv"
    attack = library.load("type-a", links=[12], offset_m=2.0, start_s=3.0)
    counts = asyncio.run(_record_sim(tlog, truth, attack, scenario="formation", vehicles=2))
    assert counts.rewritten > 100  # id 12 of both vehicles
    out = tmp_path / "out"
    args = ["--scenario", "formation", "--estimators", "ekf,secekf", "--out", str(out)]
    assert main([*args, "--tlog", str(tlog), "--truth", str(truth)]) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["test_case"] == 2 and res["log"]["sysids"] == [1, 2]
    sec, ekf = res["estimators"]["secekf+attribution"], res["estimators"]["ekf"]
    assert sec["rmse_m"] < 0.15 and sec["inter_vehicle_range"]["rmse_m"] < 0.2
    assert ekf["rmse_m"] > 2 * sec["rmse_m"]
    assert sec["attack_detection_recall"] >= 0.9


def test_recorder_refuses_bad_endpoints(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mitm_proxy.tools.record import main as record_main

    assert record_main(["--listen", "udpout://127.0.0.1:14550", "--out", str(tmp_path / "a.tlog")]) == 2
    assert "udpin" in capsys.readouterr().err and not (tmp_path / "a.tlog").exists()
    assert record_main(["--listen", "tcp://127.0.0.1:5760", "--out", str(tmp_path / "b.tlog")]) == 2
    assert "tcp" in capsys.readouterr().err
    assert record_main(["--listen", "udpin://127.0.0.1:0", "--out", str(tmp_path / "c.tlog"), "--attack", "nope"]) == 2
    assert "nope" in capsys.readouterr().err


@pytest.mark.timeout(30)
def test_recorder_stops_cleanly_on_sigterm(tmp_path: Path) -> None:
    import signal
    import subprocess
    import time

    out = tmp_path / "s.tlog"
    cmd = [sys.executable, "-m", "mitm_proxy.tools.record", "--listen", "udpin://127.0.0.1:0", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 15
    while not out.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 0, stderr
    assert json.loads(stdout)["frames_in"] == 0 and out.exists()

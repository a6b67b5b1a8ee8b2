"""``secuav-eval``: offline, reproducible comparison of estimators on one scenario and one attack.

    secuav-eval --scenario anchors8 --attack type-a --estimators ekf,secekf,rarse --trials 3 --seed 0 --out out/tc1
    secuav-eval --scenario wall_hover --attack wall-spoof-two --out out/wall
    secuav-eval --scenario anchors8 --tlog flight.tlog [--truth truth.csv] [--attack none] --out out/log
    secuav-eval --scenario rec.yaml --ranges ranges.csv [--truth truth.csv] [--attack type-a] --out out/rec

``--attack`` takes a profile file, a library name (``secuav-attack list``) or
``none``; ``--param k=v`` fills a library profile's parameters. Each trial flies
the scenario headless in flightsim (seed = ``--seed`` + trial index), attacks the
framed UWB streams with the attack_profiles engine and runs every estimator; a secure
one gives two rows, as in a study's tables: ``name``, its own output (the shared
attribution off), and ``name+attribution`` (results.json: ``output`` own / attributed).
Writes ``OUT/results.json``, ``OUT/table.txt`` and the plots ``attack.png``,
``errors.png``, ``trajectory.png`` (first trial); prints the table. Same seed,
same numbers (except the measured step times). Bad input: one line naming the
file and field, exit 2, nothing written.

``--tlog F`` replaces the flight by a recorded MAVLink log (one trial): its
DISTANCE_SENSOR readings, framed on the vehicle's boot clock (see
:mod:`evaluation.tlog`); the scenario still supplies the anchors and noise.
``--ranges CSV`` does the same for recorded ranges in a plain CSV file (time,
sysid, sensor id, range; docs/recorded-ranges.md), e.g. a public dataset decoded
by ``scripts/datasets/``. ``--truth CSV`` (flightsim's ``secuav-sim --truth-csv``, same clock) scores
errors and detection against ground truth; without it errors are n/a and only
alarms, the links named per sensor id, step times (and the distance from the
autopilot's LOCAL_POSITION_NED) are reported. An ``--attack`` other than
``none`` is applied on top of the logged readings. On a recording of one vehicle's anchor ranges every estimator
takes each reading at its own time by default (estimators.aligned: the EKF by sequential updates, the others on a
window of ``--window`` seconds brought to each output time; ``--sync`` frames them instead), and a window too short
for the links' rates is refused in one line (docs/recorded-ranges.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from tqdm import tqdm

import estimators
from attack_profiles import Engine
from attack_profiles.profile import Profile
from attack_profiles.resolve import resolve_profile
from estimators.aligned import ASYNC_PARAM
from estimators.noise import CALIBRATION_PARAM, TAIL_PARAM, TRACK_PARAM
from estimators.scenario_models import model_for
from evaluation.recorded import load_recording
from evaluation.report import BASELINES, compare_with_ls, plot, summarise, table, write_results
from evaluation.trial import (
    RATE_HZ,
    SparseReadings,
    TrialResult,
    asynchronous_by_default,
    evaluate,
    run_trial,
)
from evaluation.variants import Variant, with_attribution
from secuav_common.loading import InputError, parse_params
from secuav_common.logs import add_common_flags
from secuav_common.scenario import Scenario, load_scenario, resolve_scenario_path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-eval", description=__doc__.split("\n")[0])
    p.add_argument("--scenario", required=True, help="scenario file or bundled name (anchors8, formation)")
    p.add_argument("--attack", default=None, help="profile file, library name, or 'none' (required unless --tlog)")
    p.add_argument("--param", action="append", default=[], metavar="K=V", help="library profile parameter")
    p.add_argument(
        "--estimators",
        default=None,
        help="comma-separated (default: all that run on the scenario); the baselines ls and ekf run in every table "
        "(added when missing); `secuav-plugins --builtin` lists them with their parameters",
    )
    p.add_argument("--trials", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None, help="seconds per trial (default: the scenario's)")
    p.add_argument("--leg", choices=["hover", "moving"], default="hover", help="hold the target or swing about it")
    p.add_argument("--jobs", type=int, default=1, help="trials in parallel (processes)")
    p.add_argument(
        "--dims",
        type=int,
        choices=[2, 3],
        default=3,
        help="test case 1: 3 = full position, the downward laser one more reading; 2 = its height taken as known",
    )
    p.add_argument("--out", required=True, type=Path)
    p.add_argument(
        "--tlog",
        type=Path,
        default=None,
        help="evaluate a recorded MAVLink .tlog instead of flying (one trial; --trials, --leg, --duration unused)",
    )
    p.add_argument(
        "--ranges",
        type=Path,
        default=None,
        help="evaluate recorded ranges from a CSV (t_s,sysid,sensor_id,range_m; docs/recorded-ranges.md), like --tlog",
    )
    p.add_argument(
        "--truth", type=Path, default=None, help="ground-truth CSV for --tlog/--ranges (secuav-sim --truth-csv)"
    )
    p.add_argument(
        "--rate", type=float, default=None, help="--tlog/--ranges framing rate in Hz (default: the ranges' own)"
    )
    timing = p.add_mutually_exclusive_group()
    timing.add_argument(
        "--async",
        dest="asynchronous",
        action="store_const",
        const=True,
        default=None,
        help="--tlog/--ranges (the default there for one vehicle ranging to anchors): every estimator takes every "
        "reading at its own time, the EKF by sequential updates, the others on a window of --window seconds brought "
        "to each output time (--rate) with the motion model (estimators.aligned)",
    )
    timing.add_argument(
        "--sync",
        dest="asynchronous",
        action="store_const",
        const=False,
        help="--tlog/--ranges: frame the readings at --rate, each frame's last reading per link taken as simultaneous",
    )
    p.add_argument(
        "--window",
        type=float,
        default=None,
        metavar="S",
        help="asynchronous processing: seconds of readings each output brings to its time (default: one --rate "
        "period, each reading used once); links too sparse for it are refused",
    )
    p.add_argument(
        "--calibrate",
        type=float,
        default=None,
        metavar="S",
        help="calibrate per-link offsets and the noise scale on the first S seconds (taken as attack-free; "
        "estimators.noise) before the estimators trust the readings",
    )
    p.add_argument(
        "--tail-dof",
        type=float,
        default=None,
        metavar="NU",
        help="with --calibrate: the range errors' Student-t degrees of freedom measured beforehand "
        "(docs/datasets.md), instead of fitting the tail on the window",
    )
    p.add_argument(
        "--fixed-offsets",
        action="store_true",
        help="with --calibrate: keep the window's per-link offsets for the whole run and name a link on one failed "
        "reading (default: the offsets follow the room within a drift bound, estimators.offsets)",
    )
    p.add_argument(
        "--score-from",
        type=float,
        default=None,
        metavar="S",
        help="score only steps after S seconds (default: 1 s of warm-up, after the --calibrate window if given); "
        "give the same S to runs compared with and without --calibrate",
    )
    add_common_flags(p, log_flags=False)
    return p


# meta.json's "test_case": the seed's numbering (1 anchors, 2 formation) and "wall"
TEST_CASE: dict[str, str | int] = {"wall": "wall", "formation": 2, "anchors": 1}


def resolve_attack(spec: str, params: dict[str, Any]) -> Profile | None:
    """``--attack``: ``none``, a profile file, or a library name."""
    return None if spec == "none" else resolve_profile(spec, params, "--attack")


def _check_scenario(scenario: Scenario, source: str) -> None:
    first = scenario.vehicles[0]
    if scenario.kind == "wall":
        return
    if first.sensors.uwb is None:
        reason = "the evaluation needs UWB anchor ranging (or a wall_distance target)"
        raise InputError(source, "vehicles[0].sensors.uwb", None, reason)
    if scenario.kind == "formation" and scenario.vehicles[1].sensors.uwb.anchors != first.sensors.uwb.anchors:
        reason = "both vehicles must range to the same anchors"
        raise InputError(source, "vehicles[1].sensors.uwb.anchors", None, reason)


def _estimators(given: str | None, model: Any) -> list[str]:
    """``--estimators``: names, plugin names or package.module:Class, each able to run on ``model``."""
    if given is None:
        return estimators.names(model)  # a listing: every built-in and plugin that runs on it
    names = [n.strip() for n in given.split(",") if n.strip()]
    # The undefended baselines are in every table: the snapshot least-squares fix and the EKF, first if not given.
    names = [*(b for b in BASELINES if b not in names), *names] if names else names
    for name in names:
        try:
            cls = estimators.registry.get(name)
        except ValueError as exc:
            raise InputError("--estimators", "", name, str(exc)) from None
        if not cls.applies_to(model):
            fits = ", ".join(estimators.names(model))
            raise InputError("--estimators", "", name, f"does not run on this scenario; choose from {fits}")
    if not names:
        raise InputError("--estimators", "", given, f"choose from {', '.join(estimators.names(model))}")
    return names


def _rows(names: list[str]) -> list[Variant]:
    """The table's rows, as a study has them (evaluation.variants): a secure method twice, ``name`` (its own
    output) and ``name+attribution``."""
    return [v for name in names for v in with_attribution(name, name, {}, "offline")]


Job = tuple[Scenario, Profile | None, list[Variant], int, float, str, int, dict[str, Any]]


def _trial(args: Job) -> TrialResult:
    scenario, profile, rows, seed, duration_s, leg, dims, params = args
    labels, own = [v.label for v in rows], {v.label: (v.name, v.build_params()) for v in rows}
    leg_: Any = leg
    return run_trial(scenario, profile, labels, seed, duration_s, leg_, params, dims=dims, variants=own)


def _scored(trial: TrialResult, args: argparse.Namespace) -> TrialResult:
    return trial if args.score_from is None else dataclasses.replace(trial, score_from_s=args.score_from)


def _params(args: argparse.Namespace) -> dict[str, Any]:
    if args.calibrate is None:
        return {}
    tail = {} if args.tail_dof is None else {TAIL_PARAM: args.tail_dof}
    fixed = {TRACK_PARAM: False} if args.fixed_offsets else {}
    return {CALIBRATION_PARAM: args.calibrate, **tail, **fixed}


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        scenario_path = resolve_scenario_path(args.scenario)
        scenario = load_scenario(scenario_path)
        _check_scenario(scenario, str(scenario_path))
        if args.tlog is not None and args.ranges is not None:
            raise InputError("--tlog/--ranges", "", None, "give one recording, not both")
        recorded = args.tlog is not None or args.ranges is not None
        if args.attack is None and not recorded:
            raise InputError("--attack", "", None, "required (a profile file, a library name, or 'none')")
        if not recorded and (args.truth is not None or args.rate is not None or args.asynchronous is not None
                             or args.window is not None):  # fmt: skip
            raise InputError("--truth/--rate/--async/--sync/--window", "", None, "only with --tlog or --ranges")
        if args.asynchronous and not asynchronous_by_default(scenario):
            raise InputError("--async", "", None, "needs one vehicle ranging to anchors (test case 1)")
        if args.asynchronous is None:  # the default on a recording of one vehicle's anchor ranges
            args.asynchronous = recorded and asynchronous_by_default(scenario)
        if args.window is not None and (not args.asynchronous or not 0 < args.window <= 60):
            raise InputError("--window", "", args.window, "needs asynchronous processing and must lie in (0, 60] s")
        if args.rate is not None and not 0.1 <= args.rate <= 1000.0:
            raise InputError("--rate", "", args.rate, "must lie in 0.1..1000 Hz")
        profile = resolve_attack(args.attack or "none", parse_params(args.param))
        if profile is not None:
            Engine(profile, scenario=scenario)  # checks the profile's sensor ids against the scenario
        names = _estimators(args.estimators, model_for(scenario, args.dims))
        if args.calibrate is not None and not 0 < args.calibrate <= 3600:
            raise InputError("--calibrate", "", args.calibrate, "must lie in (0, 3600] seconds")
        if args.tail_dof is not None and (args.calibrate is None or not 2 < args.tail_dof <= 1000):
            raise InputError("--tail-dof", "", args.tail_dof, "needs --calibrate and must lie in (2, 1000]")
        if args.fixed_offsets and args.calibrate is None:
            raise InputError("--fixed-offsets", "", True, "needs --calibrate (it keeps that window's offsets)")
        if args.score_from is not None and not 0 <= args.score_from <= 36000:
            raise InputError("--score-from", "", args.score_from, "must lie in 0..36000 seconds")
        if args.trials < 1 or args.jobs < 1:
            raise InputError("--trials/--jobs", "", (args.trials, args.jobs), "must be at least 1")
    except InputError as err:
        print(f"secuav-eval: {err}", file=sys.stderr)
        return 2
    if recorded:
        return _main_tlog(args, scenario, scenario_path, profile, names)
    duration = args.duration or scenario.duration_s
    jobs: list[Job] = [
        (scenario, profile, _rows(names), args.seed + i, duration, args.leg, args.dims, _params(args))
        for i in range(args.trials)
    ]
    signal.signal(signal.SIGTERM, _terminate)
    try:
        if args.jobs == 1:
            trials = [_trial(job) for job in tqdm(jobs, desc="trials", unit="trial")]
        else:
            with ProcessPoolExecutor(max_workers=args.jobs) as pool:
                trials = list(tqdm(pool.map(_trial, jobs), total=len(jobs), desc="trials", unit="trial"))
    except KeyboardInterrupt:
        print("secuav-eval: interrupted, nothing written", file=sys.stderr)
        return 130
    except SparseReadings as err:  # a calibration window shorter than the fit needs
        print(f"secuav-eval: {InputError('--calibrate', '', err.value, err.reason)}", file=sys.stderr)
        return 2
    trials = [_scored(t, args) for t in trials]
    summary = _outputs(summarise(trials), _rows(names))
    compare_with_ls(summary, clean=profile is None)
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {
        "scenario": scenario.name,
        "scenario_file": str(scenario_path),
        "attack": None if profile is None else profile.name,
        "attack_hash": None if profile is None else profile.content_hash(),
        "trials": args.trials,
        "seed": args.seed,
        "duration_s": duration,
        "leg": args.leg,
        "dims": args.dims,
        "calibration_s": args.calibrate,
        "calibration_tail_dof": args.tail_dof,
        "calibration_track": None if args.calibrate is None else not args.fixed_offsets,
        "score_from_s": trials[0].score_from_s,
        "rate_hz": RATE_HZ,
        "test_case": TEST_CASE[scenario.kind],
        "note": "errors: the first vehicle's horizontal position (wall case: the wall distance); "
        "step times are measured, so they vary by machine",
    }
    _write(args.out, meta, summary, trials[0])
    return 0


def _outputs(summary: dict[str, dict[str, Any]], rows: list[Variant]) -> dict[str, dict[str, Any]]:
    """Each row says what it scores, under the study's column name: ``output`` own or attributed."""
    for v in rows:
        summary[v.label] = {"output": v.output, **summary[v.label]}
    return summary


def _write(out: Path, meta: dict[str, Any], summary: dict[str, dict[str, Any]], first: TrialResult) -> None:
    write_results(out, meta, summary)
    text = table(summary)
    if not first.scored_errors:
        text += "\nErrors n/a: no ground truth (give --truth); alarms and links named per sensor id: results.json."
    (out / "table.txt").write_text(text + "\n")
    plot(out, first)
    print(text)
    print(f"wrote {out / 'results.json'}, table.txt, attack.png, errors.png, trajectory.png")


def _main_tlog(
    args: argparse.Namespace, scenario: Scenario, scenario_path: Path, profile: Profile | None, names: list[str]
) -> int:
    """One trial on a recorded log or recorded-ranges CSV (see the module docstring)."""
    try:
        rec = load_recording(scenario, tlog=args.tlog, ranges=args.ranges, truth=args.truth, rate_hz=args.rate)
        streams, info, skipped, rate, boot_offset_s = (
            rec.streams, rec.info, rec.rows_skipped, rec.rate_hz, rec.boot_offset_s
        )
        engine = None if profile is None else Engine(profile, seed=args.seed, scenario=scenario)
    except InputError as err:
        print(f"secuav-eval: {err}", file=sys.stderr)
        return 2
    rows = _rows(names)
    try:
        trial = evaluate(scenario, streams, engine, [v.label for v in rows], from_log=True, params=_params(args),
                         dims=args.dims, variants={v.label: (v.name, v.build_params()) for v in rows},
                         asynchronous=args.asynchronous, window_s=args.window)  # fmt: skip
    except SparseReadings as err:
        flag = {CALIBRATION_PARAM: "--calibrate", ASYNC_PARAM: "--window"}.get(err.option, "--rate")
        print(f"secuav-eval: {InputError(str(args.ranges or args.tlog), flag, err.value, err.reason)}", file=sys.stderr)
        return 2
    trial = _scored(trial, args)
    summary = _outputs(summarise([trial]), rows)
    # A log recorded behind an attack is not clean even without --attack: only an evaluation that injects
    # nothing and has truth calls a method's loss to least squares a clean-data loss.
    compare_with_ls(summary, clean=profile is None and trial.scored_errors)
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {
        "source": "tlog" if args.tlog is not None else "ranges",
        "tlog": None if args.tlog is None else str(args.tlog),
        "ranges": None if args.ranges is None else str(args.ranges),
        "truth": None if args.truth is None else str(args.truth),
        "scenario": scenario.name,
        "scenario_file": str(scenario_path),
        "attack": None if profile is None else profile.name,
        "attack_hash": None if profile is None else profile.content_hash(),
        "trials": 1,
        "seed": args.seed,
        "calibration_s": args.calibrate,
        "calibration_tail_dof": args.tail_dof,
        "calibration_track": None if args.calibrate is None else not args.fixed_offsets,
        "score_from_s": trial.score_from_s,
        "rate_hz": round(rate, 6),
        # How each estimator took the readings: sequential updates or an aligned window (asynchronous, the
        # default) or the frames (--sync); and the window.
        "processing": trial.processing,
        "async_window_s": trial.async_window_s,
        "frames": int(trial.t_s.size),
        "boot_time_of_t0_s": boot_offset_s,
        "log": {
            "messages_read": info.frames_read,
            "sysids": list(info.sysids),
            "sensor_ids": {str(k): list(v) for k, v in info.sensor_ids.items()},
            "invalid_readings": info.invalid_readings,
            "rows_skipped": skipped,
        },
        "test_case": TEST_CASE[scenario.kind],
        "errors_scored": trial.scored_errors,
        "detection_scored": trial.scored_detection,
        "note": "errors against the truth CSV joined on the vehicle boot clock; with truth, a reading counts as "
        "attacked (recall) when it deviates from the true range by more than 5 sigma, and a named reading as "
        "rightly named (precision) when it deviates by more than 3 sigma"
        if trial.scored_errors
        else "no ground truth: errors not scored; alarms, links named per sensor id, step times and the "
        "deviation from LOCAL_POSITION_NED (the autopilot's estimate, not truth) are reported",
    }
    _write(args.out, meta, summary, trial)
    return 0


if __name__ == "__main__":
    sys.exit(main())

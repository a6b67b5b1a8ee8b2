"""``secuav-eval``: offline, reproducible comparison of estimators on one scenario and one attack.

    secuav-eval --scenario anchors8 --attack type-a --estimators ekf,secekf,rarse --trials 3 --seed 0 --out out/tc1
    secuav-eval --scenario wall_hover --attack wall-spoof-two --out out/wall

``--attack`` takes a profile file, a library name (``secuav-attack list``) or
``none``; ``--param k=v`` fills a library profile's parameters. Each trial flies
the scenario headless in flightsim (seed = ``--seed`` + trial index), attacks the
framed UWB streams with the attack_profiles engine and runs every estimator.
Writes ``OUT/results.json``, ``OUT/table.txt`` and the plots ``attack.png``,
``errors.png``, ``trajectory.png`` (first trial); prints the table. Same seed,
same numbers (except the measured step times). Bad input: one line naming the
file and field, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import yaml
from tqdm import tqdm

import estimators
from attack_profiles import Engine, library, load_profile
from attack_profiles.profile import Profile
from evaluation.report import plot, summarise, table, write_results
from evaluation.trial import RATE_HZ, TrialResult, is_formation, is_wall, run_trial
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario, load_scenario, resolve_scenario_path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-eval", description=__doc__.split("\n")[0])
    p.add_argument("--scenario", required=True, help="scenario file or bundled name (anchors8, formation)")
    p.add_argument("--attack", required=True, help="profile file, library name, or 'none'")
    p.add_argument("--param", action="append", default=[], metavar="K=V", help="library profile parameter")
    p.add_argument("--estimators", default=",".join(estimators.names()), help="comma-separated (default: all)")
    p.add_argument("--trials", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None, help="seconds per trial (default: the scenario's)")
    p.add_argument("--leg", choices=["hover", "moving"], default="hover", help="hold the target or swing about it")
    p.add_argument("--jobs", type=int, default=1, help="trials in parallel (processes)")
    p.add_argument("--out", required=True, type=Path)
    return p


def _params(pairs: list[str]) -> dict[str, Any]:
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise InputError("--param", pair, pair, "expected K=V")
        out[key] = yaml.safe_load(value)
    return out


def _profile(spec: str, params: dict[str, Any]) -> Profile | None:
    if spec == "none":
        return None
    if Path(spec).exists() or Path(spec).suffix in (".yaml", ".yml", ".json"):
        return load_profile(spec, **params)
    if spec not in library.names():
        known = ", ".join(library.names())
        raise InputError("--attack", "", spec, f"no such file or library profile; library: {known}")
    return library.load(spec, **params)


def _check_scenario(scenario: Scenario, source: str) -> None:
    first = scenario.vehicles[0]
    if is_wall(scenario):
        return
    if first.sensors.uwb is None:
        reason = "the evaluation needs UWB anchor ranging (or a wall_distance target)"
        raise InputError(source, "vehicles[0].sensors.uwb", None, reason)
    if is_formation(scenario) and scenario.vehicles[1].sensors.uwb.anchors != first.sensors.uwb.anchors:
        reason = "both vehicles must range to the same anchors"
        raise InputError(source, "vehicles[1].sensors.uwb.anchors", None, reason)


def _trial(args: tuple[Scenario, Profile | None, list[str], int, float, str]) -> TrialResult:
    return run_trial(*args)  # type: ignore[arg-type]


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        scenario_path = resolve_scenario_path(args.scenario)
        scenario = load_scenario(scenario_path)
        _check_scenario(scenario, str(scenario_path))
        profile = _profile(args.attack, _params(args.param))
        if profile is not None:
            Engine(profile, scenario=scenario)  # checks the profile's sensor ids against the scenario
        names = [n.strip() for n in args.estimators.split(",") if n.strip()]
        unknown = [n for n in names if n not in estimators.names()]
        if unknown or not names:
            raise InputError("--estimators", "", args.estimators, f"choose from {', '.join(estimators.names())}")
        if args.trials < 1 or args.jobs < 1:
            raise InputError("--trials/--jobs", "", (args.trials, args.jobs), "must be at least 1")
    except InputError as err:
        print(f"secuav-eval: {err}", file=sys.stderr)
        return 2
    duration = args.duration or scenario.duration_s
    jobs = [(scenario, profile, names, args.seed + i, duration, args.leg) for i in range(args.trials)]
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
    summary = summarise(trials)
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
        "rate_hz": RATE_HZ,
        "test_case": "wall" if is_wall(scenario) else 2 if is_formation(scenario) else 1,
        "note": "errors: the first vehicle's horizontal position (wall case: the wall distance); "
        "step times are measured, so they vary by machine",
    }
    write_results(args.out, meta, summary)
    text = table(summary)
    (args.out / "table.txt").write_text(text + "\n")
    plot(args.out, trials[0])
    print(text)
    print(f"wrote {args.out / 'results.json'}, table.txt, attack.png, errors.png, trajectory.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

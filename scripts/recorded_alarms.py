"""Every estimator on recorded ranges, framed and asynchronous, both datasets, and the held-out layouts (issue 34).

One command from the raw data prints the whole report as markdown (docs/recorded-ranges.md, "All estimators, both
datasets, both modes"); each cell's progress goes to stderr:

    .venv/bin/python scripts/recorded_alarms.py --lias-source DIR --hanyang-source DIR --heldout --jobs 2 > report.md

or, on folders already written by ``lias_planar_uwb.py convert`` / ``hanyang_outdoor_uwb.py convert``:

    .venv/bin/python scripts/recorded_alarms.py out/lias-mid-0 out/lias-fast-0 [--fixed-offsets] [--mode sync]

The documented protocol of docs/recorded-ranges.md: output at 10 Hz, ``--dims 2``, calibrated on the first 20 s,
scored from 21 s; attacks from 30 s on the profile clock, added to the recorded readings as ``secuav-eval --attack``
does: +1.5 m (``anchors-constant``) and 0.1 m/s (``anchors-ramp``) on two links, 11 and 14 on LIAS, 11 and 13 on
Hanyang, and +1.5 m on link 11 alone. Each recording runs framed (``--sync``) and asynchronously (the default of
``secuav-eval``), through the same library calls as ``secuav-eval`` (``evaluation.trial.evaluate``,
``evaluation.report.summarise``). Per estimator (the baselines ``ls`` and ``ekf`` first, then every built-in that
runs on the recording), per recording and pooled per dataset: clean RMSE and worst error, RMSE over least squares',
honest links named and alarms on the clean run (share of scored steps and events per hour:
``false_accusation_per_step``, ``false_accusations_per_hour``, ``false_alarm_per_step``, ``false_alarms_per_hour``);
under the bias and the ramp, the share of attacked steps naming both attacked links and the RMSE; the same for the
bias on the first link alone (with four anchors in 2-D one wrong link can be detected, two cannot:
docs/datasets.md); under the ramp, how large it was when first named on each link (the larger of the two).
``--heldout`` adds the held-out layouts at sigma 0.3 m (flights, framed; estimators/README.md): RMSE over the EKF's,
clean, type-a on two links and a relay on three.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from attack_profiles import Engine
from attack_profiles.profile import Profile
from attack_profiles.resolve import resolve_profile
from estimators import registry
from estimators.noise import CALIBRATION_PARAM, TRACK_PARAM
from estimators.scenario_models import anchor_model
from evaluation.recorded import load_recording
from evaluation.report import summarise
from evaluation.trial import TrialResult, evaluate, run_trial
from secuav_common.scenario import Scenario, load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parent.parent
DATASETS = {  # scenario name prefix (what the converters write) -> label and the two attacked links
    "lias": ("LIAS (eight anchors indoors, motion capture)", (11, 14)),
    "hanyang": ("Hanyang (four anchors outdoors, RTK)", (11, 13)),
}
MODES = {"sync": "framed", "async": "asynchronous"}
ATTACKS = ("clean", "bias", "bias1", "ramp")
SLOW = {"milp": 0, "poly": 1, "l0": 2}  # started first, so that the pool ends together
HELDOUT_CELLS = ("clean", "type-a", "relay")


@dataclass(frozen=True)
class Protocol:
    rate_hz: float = 10.0
    calibrate_s: float = 20.0
    score_from_s: float = 21.0
    onset_s: float = 30.0
    bias_m: float = 1.5
    ramp_mps: float = 0.1
    fixed_offsets: bool = False
    window_s: float | None = None


@dataclass(frozen=True)
class Cell:
    """One recording, processing mode, attack and estimator: one ``evaluate`` call."""

    folder: Path
    mode: str
    attack: str
    estimator: str
    links: tuple[int, ...]

    def label(self) -> str:
        return f"{self.folder.name} {self.mode} {self.attack} {self.estimator}"


@lru_cache(maxsize=8)
def _recording(folder: Path, rate_hz: float) -> tuple[Scenario, Any]:
    scenario = load_scenario(folder / "scenario.yaml")
    rec = load_recording(scenario, ranges=folder / "ranges.csv", truth=folder / "truth.csv", rate_hz=rate_hz)
    return scenario, rec.streams


def _attack(cell: Cell, proto: Protocol) -> Profile | None:
    links = {"links": list(cell.links[:1] if cell.attack == "bias1" else cell.links), "start_s": proto.onset_s}
    if cell.attack in ("bias", "bias1"):
        return resolve_profile("anchors-constant", {**links, "offset_m": proto.bias_m}, "--attack")
    if cell.attack == "ramp":
        return resolve_profile("anchors-ramp", {**links, "rate_per_s": proto.ramp_mps}, "--attack")
    return None


def run_cell(cell: Cell, proto: Protocol) -> TrialResult:
    """What ``secuav-eval --ranges --dims 2 --rate R --calibrate S --score-from F [--sync] [--attack ...]`` runs."""
    scenario, streams = _recording(cell.folder, proto.rate_hz)
    profile = _attack(cell, proto)
    engine = None if profile is None else Engine(profile, seed=0, scenario=scenario)
    params: dict[str, Any] = {CALIBRATION_PARAM: proto.calibrate_s}
    if proto.fixed_offsets:
        params[TRACK_PARAM] = False
    asynchronous = cell.mode == "async"
    trial = evaluate(scenario, streams, engine, [cell.estimator], from_log=True, params=params, dims=2,
                     asynchronous=asynchronous, window_s=proto.window_s if asynchronous else None)  # fmt: skip
    return replace(trial, score_from_s=proto.score_from_s)


@dataclass(frozen=True)
class Flight:
    """One held-out layout, cell and seed: one headless flight at sigma 0.3 m, hover, every estimator asked."""

    layout: int
    cell: str
    seed: int
    estimator: str
    duration_s: float

    def label(self) -> str:
        return f"heldout{self.layout} {self.cell} seed {self.seed} {self.estimator}"


def heldout_scenario(layout: int, sigma_m: float) -> Scenario:
    """The frozen layout with every UWB link's noise std set to ``sigma_m`` (told to the estimators too)."""
    text = (ROOT / "studies" / "scenarios" / f"heldout{layout}.yaml").read_text()
    if text.count("noise_std_m: 0.1,") != 1:
        raise ValueError(f"heldout{layout}.yaml: expected one UWB 'noise_std_m: 0.1,'")
    return parse_scenario(text.replace("noise_std_m: 0.1,", f"noise_std_m: {sigma_m},"), f"heldout{layout}")


def heldout_attack(layout: int, cell: str, onset_s: float = 8.0) -> Profile | None:
    """The attacked links and the type-a offset of ``studies/heldout-L.yaml``; the relay at +0.5 m; onset 8 s."""
    attacks = yaml.safe_load((ROOT / "studies" / f"heldout-{layout}.yaml").read_text())["attacks"]
    if cell == "clean":
        return None
    if cell == "type-a":
        p = next(a for a in attacks if isinstance(a, dict) and a["profile"] == "type-a")["params"]
        params = {"links": p["links"][0], "offset_m": p["offset_m"][0], "start_s": onset_s}
        return resolve_profile("type-a", params, "--attack")
    p = next(a for a in attacks if isinstance(a, dict) and a["profile"] == "anchors-relay")["params"]
    return resolve_profile("anchors-relay", {"links": p["links"][0], "excess_m": 0.5, "start_s": onset_s}, "--attack")


def run_flight(flight: Flight, sigma_m: float) -> TrialResult:
    scenario = heldout_scenario(flight.layout, sigma_m)
    profile = heldout_attack(flight.layout, flight.cell)
    return run_trial(scenario, profile, [flight.estimator], flight.seed, flight.duration_s, "hover")


def _timed(work: Callable[[Any, Any], TrialResult], task: Any, extra: Any) -> tuple[TrialResult, float]:
    began = time.monotonic()
    return work(task, extra), time.monotonic() - began


def _run_all(
    tasks: list[Any], work: Callable[[Any, Any], TrialResult], extra: Any, jobs: int
) -> dict[Any, TrialResult]:
    """Every task, ``jobs`` worker processes at a time, one progress line per task on stderr."""
    done: dict[Any, TrialResult] = {}
    start = time.monotonic()

    def note(task: Any, seconds: float) -> None:
        print(f"[{len(done)}/{len(tasks)}] {task.label()}: {seconds:.1f} s ({time.monotonic() - start:.0f} s in all)",
              file=sys.stderr, flush=True)  # fmt: skip

    if jobs <= 1:
        for task in tasks:
            done[task], seconds = _timed(work, task, extra)
            note(task, seconds)
        return done
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(_timed, work, task, extra): task for task in tasks}
        for future in as_completed(futures):
            done[futures[future]], seconds = future.result()
            note(futures[future], seconds)
    return done


# ---- figures --------------------------------------------------------------------------------------------------


def clean_figures(trials: list[TrialResult], name: str) -> dict[str, float | None]:
    row = summarise(trials)[name]
    keys = ("rmse_m", "max_error_m", "false_accusation_per_step", "false_accusations_per_run",
            "false_accusations_per_hour", "false_alarm_per_step", "false_alarms_per_run",
            "false_alarms_per_hour")  # fmt: skip
    return {k: row[k] for k in keys}


def attack_figures(trials: list[TrialResult], name: str, links: tuple[int, ...]) -> dict[str, float]:
    """Both attacked links named on the scored steps the attack changed; the largest attack offset when each link
    was first named (inf: never); the RMSE over every scored step, as ``summarise``."""
    hits = steps = 0
    named_at = 0.0
    for tr in trials:
        cols = [tr.sensor_ids.index(sid) for sid in links]
        added = np.abs(np.nan_to_num(tr.added_m[:, cols], nan=0.0)) if tr.added_m is not None else None
        if added is None:
            raise ValueError("the attack's added offsets are unknown")
        named = tr.traces[name].named[:, cols]
        touched = (added > 0.0) & (tr.t_s > tr.score_from_s)[:, None]
        attacked = touched.any(axis=1)
        hits += int((attacked & named.all(axis=1)).sum())
        steps += int(attacked.sum())
        for j in range(len(cols)):
            first = np.flatnonzero(touched[:, j] & named[:, j])
            named_at = max(named_at, float(added[first[0], j]) if first.size else np.inf)
    return {"recall": hits / steps if steps else np.nan, "named_at_m": named_at,
            "rmse_m": summarise(trials)[name]["rmse_m"]}  # fmt: skip


def _f(value: float | None, digits: int) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _share(share: float | None, per_hour: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.1f} % ({_f(per_hour, 0)}/h)"


def _named_at(value: float) -> str:
    return "never" if value == np.inf else f"{value:.2f}"


@dataclass(frozen=True)
class Figures:
    """One estimator's figures in one mode, on one recording or pooled over several."""

    clean: dict[str, float | None]
    ls_rmse_m: float | None
    bias: dict[str, float]
    bias1: dict[str, float]
    ramp: dict[str, float]

    @staticmethod
    def of(
        results: dict[Cell, TrialResult], members: list[Path], mode: str, name: str, links: tuple[int, ...]
    ) -> Figures:
        def trials(attack: str, est: str = name) -> list[TrialResult]:
            return [results[Cell(f, mode, attack, est, links)] for f in members]

        ls_rmse = clean_figures(trials("clean", "ls"), "ls")["rmse_m"]
        bias, ramp = (attack_figures(trials(attack), name, links) for attack in ("bias", "ramp"))
        bias1 = attack_figures(trials("bias1"), name, links[:1])
        return Figures(clean_figures(trials("clean"), name), ls_rmse, bias, bias1, ramp)

    def cells(self) -> list[str]:
        c = self.clean
        ratio = c["rmse_m"] / self.ls_rmse_m if c["rmse_m"] is not None and self.ls_rmse_m else None
        return [_f(c["rmse_m"], 3), _f(c["max_error_m"], 2), _f(ratio, 2),
                _share(c["false_accusation_per_step"], c["false_accusations_per_hour"]),
                _share(c["false_alarm_per_step"], c["false_alarms_per_hour"]),
                _f(self.bias["recall"], 3), _f(self.bias["rmse_m"], 3),
                _f(self.bias1["recall"], 3), _f(self.bias1["rmse_m"], 3),
                _f(self.ramp["recall"], 3), _named_at(self.ramp["named_at_m"]), _f(self.ramp["rmse_m"], 3)]  # fmt: skip


def dataset_table(
    label: str, links: tuple[int, ...], folders: list[Path], names: list[str], modes: list[str],
    results: dict[Cell, TrialResult], proto: Protocol,
) -> list[str]:  # fmt: skip
    """One markdown table: a row per recording and estimator, and pooled rows when there are several recordings;
    each cell the modes' figures side by side (framed / asynchronous)."""
    on = ", ".join(str(s) for s in links)
    lines = [
        f"**{label}** (each cell: {' / '.join(MODES[m] for m in modes)})",
        "",
        f"| recording | estimator | clean RMSE [m] | clean max [m] | clean RMSE / LS | honest link named, clean steps "
        f"(per hour) | alarms, clean steps (per hour) | +{proto.bias_m:g} m on {on}: both named | RMSE [m] | "
        f"+{proto.bias_m:g} m on {links[0]} alone: named | RMSE [m] | "
        f"{proto.ramp_mps:g} m/s ramp on {on}: both named | named at [m] | RMSE [m] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    groups = [(f.name, [f]) for f in folders] + ([(f"all {len(folders)}", folders)] if len(folders) > 1 else [])
    for group, members in groups:
        for name in names:
            per_mode = [Figures.of(results, members, mode, name, links).cells() for mode in modes]
            sides = [" / ".join(values) for values in zip(*per_mode, strict=True)]
            lines.append(f"| {group} | {name} | {' | '.join(sides)} |")
    return lines


def heldout_table(flights: dict[Flight, TrialResult], layouts: list[int], names: list[str]) -> list[str]:
    """RMSE over the EKF's on the same flights (seeds pooled), per layout and cell."""
    others = [n for n in names if n != "ekf"]
    lines = [f"| layout | cell | EKF RMSE [m] | {' | '.join(others)} |", "|---|---|---|" + "---|" * len(others)]
    for layout in layouts:
        for cell in HELDOUT_CELLS:
            rmse = {
                name: summarise(
                    [tr for f, tr in flights.items() if (f.layout, f.cell, f.estimator) == (layout, cell, name)]
                )[name]["rmse_m"]
                for name in names
            }
            ekf = rmse["ekf"]
            ratios = " | ".join(f"{rmse[n] / ekf:.2f}x" for n in others)
            what = {"clean": "clean", "type-a": "type-a on two links (within s)",
                    "relay": "relay +0.5 m on three links (beyond s)"}[cell]  # fmt: skip
            lines.append(f"| {layout} | {what} | {ekf:.3f} | {ratios} |")
    return lines


# ---- recordings -------------------------------------------------------------------------------------------------


def convert(work: Path, lias: Path | None, lias_runs: Iterable[str], hanyang: Path | None,
            hanyang_runs: Iterable[str]) -> list[Path]:  # fmt: skip
    """Convert the documented recordings (LIAS tag 0 of each run; Hanyang ENV:CASE) into ``work``."""
    jobs: list[tuple[Path, list[str]]] = []
    if lias is not None:
        for run in lias_runs:
            out = work / f"lias-{run}-0"
            jobs.append((out, ["lias_planar_uwb.py", "--source", str(lias), "--run", run, "--tag", "0"]))
    if hanyang is not None:
        for spec in hanyang_runs:
            env, case = spec.split(":")
            out = work / f"hy-{env.lower()}-{case}"
            jobs.append((out, ["hanyang_outdoor_uwb.py", "--source", str(hanyang), "--env", env, "--case", case]))
    for out, (script, *args) in jobs:
        cmd = [sys.executable, str(ROOT / "scripts" / "datasets" / script), "convert", *args, "--out", str(out)]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"recorded_alarms: {' '.join(cmd[1:])}: {done.stderr.strip()}")
        print(done.stdout.strip(), file=sys.stderr)
    return [out for out, _ in jobs]


def dataset_of(scenario: Scenario, links: tuple[int, ...] | None) -> tuple[str, tuple[int, ...]]:
    for prefix, (label, default) in DATASETS.items():
        if scenario.name.startswith(prefix):
            return label, links or default
    if links is None:
        raise SystemExit(f"recorded_alarms: {scenario.name}: not a LIAS or Hanyang recording; give --links")
    return scenario.name, links


def estimator_names(scenario: Scenario, asked: str | None, dims: int = 2) -> list[str]:
    """The baselines first, then the asked estimators (default: every built-in that runs on the scenario)."""
    model = anchor_model(scenario, scenario.vehicles[0].sysid, dims)
    fits = [n for n in registry.builtin_names() if registry.get(n).applies_to(model)]
    chosen = fits if asked is None else [n.strip() for n in asked.split(",") if n.strip()]
    return [*(b for b in ("ls", "ekf") if b not in chosen), *chosen]


def _commit() -> str:
    done = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True,
                          text=True, check=False)  # fmt: skip
    return done.stdout.strip() or "unknown"


@contextlib.contextmanager
def _markdown_out() -> Iterator[TextIO]:
    """The report's stream, the process's stdout, while file descriptor 1 points at stderr: a solver's C code (HiGHS,
    in milp) prints to descriptor 1, in the worker processes too, and must not land in the markdown."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    out = os.fdopen(os.dup(saved), "w")
    try:
        yield out
    finally:
        out.close()
        os.dup2(saved, 1)
        os.close(saved)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recordings", nargs="*", type=Path, help="folders written by a converter in scripts/datasets")
    ap.add_argument("--lias-source", type=Path, help="a copy of LIAS Planar_Dataset/Dynamic: convert tag 0 first")
    ap.add_argument("--lias-runs", default="mid,fast", help="LIAS runs to convert (comma-separated)")
    ap.add_argument("--hanyang-source", type=Path, help="a copy of the Hanyang UWB dataset: convert first")
    ap.add_argument("--hanyang-runs", default="LOS:4,NLOS:3", help="Hanyang ENV:CASE runs to convert")
    ap.add_argument("--work", type=Path, help="where converted recordings go (default: a temporary folder)")
    ap.add_argument("--estimators", default=None, help="default: every built-in that runs on the recording")
    ap.add_argument("--mode", choices=("both", "sync", "async"), default="both",
                    help="framed (--sync), asynchronous (secuav-eval's default) or both side by side")  # fmt: skip
    ap.add_argument("--links", default=None, help="the two attacked sensor ids (default: the dataset's)")
    ap.add_argument("--fixed-offsets", action="store_true", help="the window's offsets for the whole run")
    ap.add_argument("--ramp-mps", type=float, default=0.1, help="the ramp's rate (m/s)")
    ap.add_argument("--bias-m", type=float, default=1.5, help="the bias (m)")
    ap.add_argument("--rate", type=float, default=10.0, help="output (framing) rate, Hz")
    ap.add_argument("--calibrate", type=float, default=20.0, help="calibration window, s")
    ap.add_argument("--score-from", type=float, default=21.0, help="first scored time, s")
    ap.add_argument("--onset", type=float, default=30.0, help="attack onset on the profile clock, s")
    ap.add_argument("--window", type=float, default=None, help="asynchronous window, s (default one period)")
    ap.add_argument("--heldout", action="store_true", help="add the held-out layouts at sigma 0.3 m")
    ap.add_argument("--heldout-seeds", type=int, default=3, help="flights per cell, seeds 200 on")
    ap.add_argument("--heldout-duration", type=float, default=30.0, help="seconds per held-out flight")
    ap.add_argument("--heldout-estimators", default=None, help="default: every built-in that runs in 3-D")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    args = ap.parse_args(argv)
    began = time.monotonic()
    proto = Protocol(args.rate, args.calibrate, args.score_from, args.onset, args.bias_m, args.ramp_mps,
                     args.fixed_offsets, args.window)  # fmt: skip
    links = None if args.links is None else tuple(int(s) for s in args.links.split(","))
    modes = ["sync", "async"] if args.mode == "both" else [args.mode]
    with _markdown_out() as out, tempfile.TemporaryDirectory(prefix="r-report-") as tmp:
        work = args.work or Path(tmp)
        folders = [*args.recordings, *convert(work, args.lias_source, args.lias_runs.split(","),
                                              args.hanyang_source, args.hanyang_runs.split(","))]  # fmt: skip
        if not folders and not args.heldout:
            ap.error("give recordings, --lias-source/--hanyang-source, or --heldout")
        groups: dict[str, tuple[tuple[int, ...], list[Path], list[str]]] = {}
        for folder in folders:
            scenario = load_scenario(folder / "scenario.yaml")
            label, their_links = dataset_of(scenario, links)
            names = estimator_names(scenario, args.estimators)
            groups.setdefault(label, (their_links, [], names))[1].append(folder)
        cells = [Cell(f, mode, attack, name, their)
                 for their, members, names in groups.values() for f in members
                 for mode in modes for attack in ATTACKS for name in names]  # fmt: skip
        cells.sort(key=lambda c: SLOW.get(c.estimator, len(SLOW)))
        results = _run_all(cells, run_cell, proto, args.jobs)
        print(
            f"Measured on {_commit()} by `scripts/recorded_alarms.py` (protocol: output at {proto.rate_hz:g} Hz, "
            f"--dims 2, calibrated on the first {proto.calibrate_s:g} s, scored from {proto.score_from_s:g} s, "
            f"attacks from {proto.onset_s:g} s; offsets {'fixed' if proto.fixed_offsets else 'followed'}).\n",
            file=out,
        )
        for label, (their, members, names) in groups.items():
            print("\n".join(dataset_table(label, their, members, names, modes, results, proto)) + "\n", file=out)
        if args.heldout:
            heldout(args, out)
    print(f"recorded_alarms: {time.monotonic() - began:.0f} s, {os.cpu_count()} cores", file=sys.stderr)
    return 0


def heldout(args: argparse.Namespace, out: TextIO) -> None:
    """The held-out layouts' table (``--heldout``): every flight, then the table on ``out``."""
    layouts = [1, 2, 3]
    names = estimator_names(heldout_scenario(1, 0.3), args.heldout_estimators, dims=3)
    flights = [Flight(layout, cell, 200 + i, name, args.heldout_duration) for layout in layouts
               for cell in HELDOUT_CELLS for i in range(args.heldout_seeds) for name in names]  # fmt: skip
    flights.sort(key=lambda f: SLOW.get(f.estimator, len(SLOW)))
    done = _run_all(flights, run_flight, 0.3, args.jobs)
    seeds = f"seeds 200-{199 + args.heldout_seeds} pooled, {args.heldout_duration:g} s each"
    print(f"**Held-out layouts at sigma 0.3 m** (hover, onset 8 s, {seeds}, framed; RMSE over the EKF's on the same "
          "flights)\n", file=out)  # fmt: skip
    print("\n".join(heldout_table(done, layouts, names)) + "\n", file=out)


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python
"""Print the result tables of estimators/README.md from the stored study rows (nothing typed in by hand).

Usage (after running the bundled studies into out/):
    .venv/bin/python scripts/estimator_tables.py --out out

Reads out/test-case-1, out/test-case-1-exact, out/test-case-1-2d, out/false-alarms,
out/false-alarms-nlos, out/test-case-2 and out/false-alarms-formation where they exist and prints one
Markdown table each: means over seeds with 95 % bootstrap intervals where the
study report gives them (study.report.mean_ci), and the l0 worst-case error
bound of estimators.bounds at each hover point beside the measured worst case.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimators.bounds import l0_error_bound  # noqa: E402
from estimators.scenario_models import anchor_model  # noqa: E402
from secuav_common.scenario import load_scenario  # noqa: E402
from study.report import labelled, mean_ci  # noqa: E402
from study.store import load  # noqa: E402

CENTRE = "[2.5,2.5]"
# Library attacks on more links than test case 1 tolerates (s = 2): relay three links, overwhelm four.
BEYOND = ("anchors-relay", "anchors-overwhelm")
Pick = Callable[[pd.DataFrame], pd.DataFrame]


# These tables are of the estimators as SecUAV runs them live: a secure method's output with the shared
# attribution (its +attribution row, shown under its name), the undefended ones as they are. Their detection
# figures: the attribution's where it ran, else the method's own naming; a method that names nothing: 0.
LEGACY = {"false_alarm_rate": "false_naming", "recall_all": "recall", "precision_all": "precision",
          "detection_delay_s": "detection_delay_s"}  # fmt: skip


def _ok(out: Path) -> pd.DataFrame | None:
    if not (out / "results.parquet").is_dir():
        return None
    frame = load(out)
    frame = frame[frame["status"] == "ok"]
    if "output" in frame and frame["output"].notna().any():
        attributed = set(frame.loc[frame["output"] == "attributed", "estimator_name"])
        frame = frame[(frame["output"] == "attributed") | ~frame["estimator_name"].isin(attributed)]
        frame = frame.assign(estimator=frame["estimator"].str.replace("+attribution", "", regex=False))
        for legacy, figure in LEGACY.items():
            value = frame[f"attribution_{figure}"].fillna(frame[f"own_{figure}"])
            frame = frame.assign(**{legacy: value.fillna(0.0) if figure == "false_naming" else value})
    return labelled(frame)


def _params(frame: pd.DataFrame, **want: object) -> pd.DataFrame:
    keep = [all(json.loads(p or "{}").get(k) == v for k, v in want.items()) for p in frame["params"]]
    return frame.loc[np.array(keep, dtype=bool)]  # a boolean mask (an empty list would select columns)


def _cell(frame: pd.DataFrame, metric: str, digits: int = 3, ci: bool = True) -> str:
    mean, lo, hi, n = mean_ci(frame[metric].tolist())
    if mean is None:
        return "n/a"
    if not ci or lo is None or hi is None or n < 2:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _share(frame: pd.DataFrame, metric: str) -> str:
    values = frame[metric].dropna()
    return "n/a" if not len(values) else f"{values.mean():.0%}"


def _table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def test_case_1(frame: pd.DataFrame) -> str:
    """Centre hover: the attacks of a review, one column each."""
    centre = frame[(frame["position"] == CENTRE) & (frame["leg"] == "hover")]
    columns: list[tuple[str, Pick, str]] = [
        ("clean RMSE [m]", lambda f: f[f["attack"] == "none"], "rmse_m"),
        ("clean: honest named", lambda f: f[f["attack"] == "none"], "false_alarm_rate"),
        ("clean NEES", lambda f: f[f["attack"] == "none"], "nees_mean"),
        ("stealthy 2 sigma RMSE [m]", lambda f: _params(f[f["attack"] == "anchors-stealthy"], sigmas=2.0), "rmse_m"),
        ("stealthy 3 sigma RMSE [m]", lambda f: _params(f[f["attack"] == "anchors-stealthy"], sigmas=3.0), "rmse_m"),
        ("stealthy 3 sigma recall", lambda f: _params(f[f["attack"] == "anchors-stealthy"], sigmas=3.0), "recall_all"),
        ("stealthy 10 sigma RMSE [m]", lambda f: _params(f[f["attack"] == "anchors-stealthy"], sigmas=10.0),
         "rmse_m"),
        ("mirror RMSE [m]", lambda f: f[f["attack"] == "anchors-mirror"], "rmse_m"),
        ("height-spoof 0.1 m/s RMSE [m]", lambda f: _params(f[f["attack"] == "height-spoof"], rate_per_s=0.1),
         "rmse_m"),
        ("its height RMSE [m]", lambda f: _params(f[f["attack"] == "height-spoof"], rate_per_s=0.1),
         "height_rmse_m"),
    ]  # fmt: skip
    over = lambda f: _params(f[f["attack"] == "anchors-overwhelm"], offset_m=1.0)  # noqa: E731
    head = ["estimator", *[c[0] for c in columns], "4 of 8 links +1 m: claimed valid", "RMSE when valid [m]",
            "precision of names", "step [ms]"]  # fmt: skip
    rows = []
    for est, g in centre.groupby("estimator", sort=False):
        cells = [str(est)]
        for _, pick, metric in columns:
            digits = 2 if metric == "nees_mean" else 3
            cells.append(_cell(pick(g), metric, digits, ci=metric not in ("nees_mean", "height_rmse_m")))
        o = over(g)
        cells += [_share(o, "valid_fraction"), _cell(o, "valid_rmse_m"), _cell(o, "precision_all", 2)]
        cells.append(f"{g['step_time_us_median'].median() / 1000:.3f}")
        rows.append(cells)
    return _table(head, rows)


def recall_by_sigma(frame: pd.DataFrame) -> str:
    """Stealthy bias on two links, centre hover: share of attacked readings named, per magnitude."""
    f = frame[(frame["attack"] == "anchors-stealthy") & (frame["position"] == CENTRE) & (frame["leg"] == "hover")]
    sigmas = sorted({json.loads(p)["sigmas"] for p in f["params"]})
    rows = []
    for est, g in f.groupby("estimator", sort=False):
        cells = [str(est)]
        for s in sigmas:
            sel = _params(g, sigmas=s)
            cells.append(f"{_cell(sel, 'recall_all', 2, ci=False)} / {_cell(sel, 'detection_delay_s', 1, ci=False)}")
        rows.append(cells)
    return _table(["estimator", *[f"{s:g} sigma: recall / delay [s]" for s in sigmas]], rows)


def worst_case(frame: pd.DataFrame, with_bound: bool) -> str:
    """Worst horizontal error over every attack within tolerance (not BEYOND) and seed, per leg and point.

    With ``with_bound`` the l0 bound of estimators.bounds heads the table: it bounds the bounded-noise l0
    decoder (milp) on steps whose honest noise lies inside 3 sigma, and only that row is comparable with it.
    """
    scenario = load_scenario("anchors8")
    model = anchor_model(scenario)
    within = frame[~frame["attack"].isin(BEYOND)]
    places = _places(within)
    rows = []
    if with_bound:
        bound = []
        for leg, pos in places:
            north, east = json.loads(pos)
            at = np.array([north, east, -2.5])
            bound.append(f"{l0_error_bound(model, at, 2, 3.0 * model.sigma_m, None, slice(0, 2)):.2f}"
                         if leg == "hover" else "n/a")  # fmt: skip
        rows.append(["l0 bound, 3-sigma noise box (bounds milp)", *bound])
    for est, g in within.groupby("estimator", sort=False):
        worst = [g[(g["leg"] == leg) & (g["position"] == pos)]["max_error_m"].max() for leg, pos in places]
        rows.append([str(est), *[f"{w:.2f}" for w in worst]])
    return _table(["worst horizontal error [m]", *[f"{leg} {pos}" for leg, pos in places]], rows)


def beyond(frame: pd.DataFrame) -> str:
    """Beyond tolerance, every place and seed: the share of steps claimed valid and the worst error then."""
    picks = _beyond_picks(frame)
    rows = []
    for est, g in frame.groupby("estimator", sort=False):
        cells = [str(est)]
        for attack, params in picks:
            sel = _params(g[g["attack"] == attack], **params)
            worst = sel["valid_max_error_m"].max()
            cells.append(f"{_share(sel, 'valid_fraction')} / {worst:.2f}" if pd.notna(worst) else "n/a")
        rows.append(cells)
    return _table(["claimed valid / worst then [m]", *_beyond_head(picks)], rows)


def _beyond_picks(frame: pd.DataFrame) -> list[tuple[str, dict[str, Any]]]:
    """The beyond-tolerance (attack, parameters) columns present in ``frame``, by attack then magnitude."""
    picks = [(a, json.loads(p)) for a, p in dict.fromkeys(zip(frame["attack"], frame["params"], strict=True))
             if a in BEYOND]  # fmt: skip
    return sorted(picks, key=lambda ap: (ap[0], sorted(ap[1].items())))


def _beyond_head(picks: list[tuple[str, dict[str, Any]]]) -> list[str]:
    return [f"{a.removeprefix('anchors-')} {', '.join(f'{v:g}' for v in p.values())} m" for a, p in picks]


def against_ekf(frame: pd.DataFrame, valid_metric: str, ekf_metric: str, digits: int) -> str:
    """Beyond tolerance, run by run: how much further from the truth an estimator is on the steps it claims valid
    than the plain EKF is, less the same difference on the clean run of the same leg, place and seed.

    A secure estimator pays for its resilience on clean data too (it leaves readings out; a snapshot does not
    smooth), so "never worse than the EKF while valid" is measured against that price: 0 means the attack cost
    the valid claim nothing beyond it, a negative value that the estimator gained on the EKF. Mean over every
    run with its 95 % bootstrap interval.
    """
    keys = ["leg", "position", "seed"]
    ekf = frame[frame["estimator"] == "ekf"][["attack", "params", *keys, ekf_metric]].rename(
        columns={ekf_metric: "ekf"}
    )
    runs = frame[~frame["estimator"].isin(["ekf", "ls"])].merge(ekf, on=["attack", "params", *keys])
    runs["gap"] = runs[valid_metric] - runs["ekf"]
    clean = runs[runs["attack"] == "none"][["estimator", *keys, "gap"]].rename(columns={"gap": "clean_gap"})
    runs = runs.merge(clean, on=["estimator", *keys])
    runs["excess"] = runs["gap"] - runs["clean_gap"]
    picks = _beyond_picks(runs)
    rows = []
    for est, g in runs.groupby("estimator", sort=False):
        rows.append([str(est), *[_cell(_params(g[g["attack"] == a], **p), "excess", digits) for a, p in picks]])
    return _table(["excess over the EKF, less clean [m]", *_beyond_head(picks)], rows)


def _places(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(leg, hover point) pairs in a stable order: hover before moving, centre first."""
    pairs = {(leg, pos) for leg, pos in zip(frame["leg"], frame["position"], strict=True) if pos}
    return sorted(pairs, key=lambda lp: (lp[0] != "hover", lp[1] != CENTRE, lp[1]))


def by_place(frame: pd.DataFrame, attack: str, params: dict[str, object]) -> str:
    """One attack at every hover point and on the moving leg: RMSE with its 95 % interval."""
    f = _params(frame[frame["attack"] == attack], **params)
    places = _places(f)
    rows = []
    for est, g in f.groupby("estimator", sort=False):
        rows.append(
            [str(est), *[_cell(g[(g["leg"] == leg) & (g["position"] == pos)], "rmse_m") for leg, pos in places]]
        )
    return _table(["RMSE [m]", *[f"{leg} {pos}" for leg, pos in places]], rows)


def false_alarms(frames: dict[str, pd.DataFrame]) -> str:
    rows = []
    for noise, frame in frames.items():
        # Estimators in study order, each one's alpha grid ascending.
        order = {name: i for i, name in enumerate(dict.fromkeys(n.split()[0] for n in frame["estimator"]))}
        for est in sorted(frame["estimator"].unique(), key=lambda label, order=order: _alpha_key(label, order)):
            g = frame[frame["estimator"] == est]
            plain = [_cell(g, m, d, ci=False) for m, d in
                     (("alarm_fraction", 4), ("rmse_m", 3), ("nees_mean", 2), ("nis_mean", 2))]  # fmt: skip
            rows.append([noise, str(est), _cell(g, "false_alarm_rate", 4), *plain])
    head = ["noise", "estimator", "honest reading named (share of steps)", "alarm", "RMSE [m]", "NEES", "NIS / dof"]
    return _table(head, rows)


def _alpha_key(label: str, order: dict[str, int]) -> tuple[int, float]:
    """Sort key of an estimator label (``secekf alpha=0.01``): the study's estimator order, then alpha."""
    name, *tuning = label.split()
    alpha = next((float(t.split("=")[1]) for t in tuning if t.startswith("alpha=")), 0.0)
    return order[name], alpha


def by_attack(frame: pd.DataFrame, picks: list[tuple[str, str, dict[str, object]]]) -> str:
    rows = []
    for est, g in frame.groupby("estimator", sort=False):
        cells = [str(est)]
        for _, attack, params in picks:
            sel = _params(g[g["attack"] == attack], **params)
            cells.append(f"{_cell(sel, 'rmse_m', 3, ci=False)} / {_cell(sel, 'recall_all', 2, ci=False)}")
        rows.append(cells)
    return _table(["estimator", *[f"{label}: RMSE [m] / recall" for label, _, _ in picks]], rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "out", help="where the studies were run (--out of each)")
    args = ap.parse_args()
    tc1 = _ok(args.out / "test-case-1")
    if tc1 is not None:
        print("## Test case 1, centre hover\n\n" + test_case_1(tc1) + "\n")
        print("## Stealthy bias: recall and detection delay by magnitude\n\n" + recall_by_sigma(tc1) + "\n")
        print("## Worst case within tolerance\n\n" + worst_case(tc1, with_bound=True) + "\n")
        print("## Beyond tolerance: claimed valid, and the worst error then\n\n" + beyond(tc1) + "\n")
        print("## Beyond tolerance against the EKF: RMSE when valid\n\n"
              + against_ekf(tc1, "valid_rmse_m", "rmse_m", 3) + "\n")  # fmt: skip
        print("## Beyond tolerance against the EKF: worst valid step\n\n"
              + against_ekf(tc1, "valid_max_error_m", "max_error_m", 2) + "\n")  # fmt: skip
        for title, attack, params in (("clean", "none", {}), ("stealthy 3 sigma", "anchors-stealthy", {"sigmas": 3.0})):
            print(f"## {title}, every place\n\n" + by_place(tc1, attack, params) + "\n")
    exact = _ok(args.out / "test-case-1-exact")
    if exact is not None:
        print("## Exact baselines, centre\n\n" + test_case_1(exact) + "\n")
        print("## The MILP against the l0 bound\n\n" + worst_case(exact, with_bound=True) + "\n")
    fa = {k: f for k in ("false-alarms", "false-alarms-nlos") if (f := _ok(args.out / k)) is not None}
    if fa:
        print("## False alarms on long clean runs\n\n" + false_alarms(fa) + "\n")
    flat = _ok(args.out / "test-case-1-2d")
    if flat is not None:
        picks = [("clean", "none", {}), ("type-a 1 m", "type-a", {"offset_m": 1.0}),
                 ("relay +1 m", "anchors-relay", {"excess_m": 1.0}), ("stealthy 3 sigma", "anchors-stealthy",
                 {"sigmas": 3.0}), ("height-spoof 0.1 m/s", "height-spoof", {"rate_per_s": 0.1})]  # fmt: skip
        centre = flat[flat["position"] == CENTRE]
        print("## The seed's 2-D split (height known), centre\n\n" + by_attack(centre, picks) + "\n")
    tc2 = _ok(args.out / "test-case-2")
    if tc2 is not None:
        picks = [("clean", "none", {}), ("type-a 1 m", "type-a", {"offset_m": 1.0}),
                 ("stealthy 3 sigma", "anchors-stealthy", {"sigmas": 3.0}),
                 ("relay +1 m", "anchors-relay", {"excess_m": 1.0})]  # fmt: skip
        hover = tc2[tc2["leg"] == "hover"]
        print("## Test case 2 (formation), hover\n\n" + by_attack(hover, picks) + "\n")
        clean = hover[hover["attack"] == "none"]
        print(false_alarms({"gaussian": clean}) + "\n")
    formation_fa = _ok(args.out / "false-alarms-formation")
    if formation_fa is not None:
        table = false_alarms({"gaussian": formation_fa})
        print("## False alarms of the formation on long clean runs\n\n" + table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

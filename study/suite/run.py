"""``secuav-study suite list|run|check``: the versioned benchmark suite (docs/bench.md).

A suite version is a folder ``study/suite/vN/``: ``suite.yaml`` (the version, the tuning budget, the study
files in order and each one's quick overrides) and the study files. ``run`` writes one study directory per
study file under ``OUT`` (``OUT/suite.json`` says which version and variant), adding the methods under test
(``--add huber``, ``--add '{name: huber, params: {huber_k: [1.0, 1.345]}}'``) to every offline study whose
scenario they run on. ``check`` reads ``OUT`` and prints the leaderboard, per study and method: mean RMSE
with its 95 % bootstrap CI, the valid fraction, detection recall, the median wall time of a cell and the
method's step time; each built-in's mean is compared with its expected band (``expected-quick.yaml``,
``expected-full.yaml``: measured, see there), and the provenance line says what computed the rows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from secuav_common.loading import InputError

SUITES = Path(__file__).resolve().parent
LATEST = "v1"


@dataclass(frozen=True)
class Entry:
    file: str
    quick: dict[str, Any] | None


def manifest(version: str = LATEST) -> tuple[dict[str, Any], list[Entry]]:
    folder = SUITES / version
    if not (folder / "suite.yaml").is_file():
        have = ", ".join(sorted(p.name for p in SUITES.glob("v*")))
        raise InputError("--version", "", version, f"no such suite (have: {have})")
    doc = yaml.safe_load((folder / "suite.yaml").read_text(encoding="utf-8"))
    return doc, [Entry(s["file"], s.get("quick")) for s in doc["studies"]]


def study_doc(version: str, entry: Entry, quick: bool) -> dict[str, Any] | None:
    """The study document as this variant runs it (None: not in this variant)."""
    doc = yaml.safe_load((SUITES / version / entry.file).read_text(encoding="utf-8"))
    if quick:
        if entry.quick is None:
            return None
        doc.update(entry.quick)
    return doc


def list_text(version: str = LATEST) -> str:
    from study.spec import expand, parse_study

    head, entries = manifest(version)
    lines = [f"SecUAV suite v{head['version']} (tuning budget {head['tuning_budget']} points per method)",
             f"{'study':<28} {'quick cells':>11} {'full cells':>10}  scenario / mode"]  # fmt: skip
    for entry in entries:
        counts = []
        for quick in (True, False):
            doc = study_doc(version, entry, quick)
            if doc is None:
                counts.append("-")
                continue
            source = str(SUITES / version / entry.file)
            counts.append(str(len(expand(parse_study(yaml.safe_dump(doc), source), source))))
        full = study_doc(version, entry, False) or {}
        lines.append(f"{Path(entry.file).stem:<28} {counts[0]:>11} {counts[1]:>10}  "
                     f"{full.get('scenario')} / {full.get('mode', 'offline')}")  # fmt: skip
    return "\n".join(lines)


def _with_added(doc: dict[str, Any], added: list[Any], budget: int) -> tuple[dict[str, Any], list[str]]:
    """The study with the methods under test appended where they run; and the names left out (with why)."""
    import estimators
    from evaluation.cli import model_for
    from secuav_common.scenario import load_scenario, resolve_scenario_path

    doc = {**doc, "tuning_budget": budget}
    if doc.get("mode", "offline") != "offline" or not added:
        return doc, []
    model = model_for(load_scenario(resolve_scenario_path(doc["scenario"])), int(doc.get("dims", 3)))
    keep, skipped = list(doc["estimators"]), []
    for entry in added:
        name = entry if isinstance(entry, str) else entry["name"]
        if estimators.registry.get(name).applies_to(model):
            keep.append(entry)
        else:
            skipped.append(f"{name} (does not run on {doc['scenario']})")
    return {**doc, "estimators": keep}, skipped


def run(out: Path, *, quick: bool, version: str, added: list[Any], runner_args: list[str],
        only: list[str] | None = None) -> int:  # fmt: skip
    """Run every study of the suite (or those in ``only``) into ``out/<study>``; the worst exit code."""
    from study.cli import main as study_main

    head, entries = manifest(version)
    stems = [Path(e.file).stem for e in entries]
    for name in only or []:
        if name not in stems:
            raise InputError("--only", "", name, f"not a study of suite {version} ({', '.join(stems)})")
    if only:
        entries = [e for e in entries if Path(e.file).stem in only]
    out.mkdir(parents=True, exist_ok=True)
    meta = {"suite": head["version"], "variant": "quick" if quick else "full", "added": added}
    held = out / "suite.json"
    if held.is_file() and json.loads(held.read_text())["variant"] != meta["variant"]:
        raise InputError(str(out), "suite.json: variant", json.loads(held.read_text())["variant"],
                         "this directory holds the other variant; use a new OUT")  # fmt: skip
    held.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    worst = 0
    for entry in entries:
        doc = study_doc(version, entry, quick)
        if doc is None:
            print(f"suite: {entry.file}: not in the quick variant", flush=True)
            continue
        doc, skipped = _with_added(doc, added, int(head["tuning_budget"]))
        for s in skipped:
            print(f"suite: {entry.file}: {s}", flush=True)
        stem = Path(entry.file).stem
        path = out / "studies" / f"{stem}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
        print(f"suite: {stem}", flush=True)
        code = study_main(["run", str(path), "--out", str(out / stem), *runner_args])
        if code == 130:  # interrupted: stop here; run again to go on (done cells are skipped)
            return code
        worst = max(worst, code)
    return worst


def _expected(version: str, variant: str) -> dict[str, dict[str, list[float]]]:
    path = SUITES / version / f"expected-{variant}.yaml"
    if not path.is_file():
        return {}
    doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    return doc.get("bands", {})


def leaderboard(out: Path, version: str = LATEST) -> tuple[pd.DataFrame, list[str]]:
    """One row per (study, method variant) over ``out``; and the provenance lines."""
    from study import store
    from study.report import BASELINE, mean_ci, secure_names

    meta = json.loads((out / "suite.json").read_text(encoding="utf-8"))
    bands = _expected(version, meta["variant"])
    rows: list[dict[str, Any]] = []
    prov: set[str] = set()
    _, entries = manifest(version)
    for entry in entries:
        stem = Path(entry.file).stem
        frame = store.load(out / stem)
        if not len(frame):
            continue
        ok = frame[frame["status"] == "ok"]
        for col in ("secuav_version", "secuav_commit", "secuav_dirty", "python_version", "numpy_version",
                    "scipy_version"):  # fmt: skip
            if col not in ok:
                ok = ok.assign(**{col: None})
        for r in ok[["secuav_version", "secuav_commit", "secuav_dirty", "python_version", "numpy_version",
                     "scipy_version"]].drop_duplicates().itertuples(index=False):  # fmt: skip
            dirty = " (dirty)" if r.secuav_dirty else ""
            prov.add(f"secuav {r.secuav_version} {str(r.secuav_commit)[:12]}{dirty}, python {r.python_version}, "
                     f"numpy {r.numpy_version}, scipy {r.scipy_version}")  # fmt: skip
        prov |= plugin_code(ok)
        clean = ok[ok["attack"] == "none"]
        secure = secure_names(ok)
        for (label, dist, version_), g in ok.groupby(["estimator", "estimator_dist", "estimator_version"],
                                                       dropna=False, sort=False):  # fmt: skip
            mean, lo, hi, n = mean_ci(g["rmse_m"])
            mine = clean[clean["estimator"] == label]["rmse_m"].mean()
            # The baseline at the same grid point of the study's estimator_params (rows of one grid point only).
            tuning = g["estimator_params"].dropna().unique() if "estimator_params" in g else []
            same = clean["estimator_params"].isin(tuning) if len(tuning) else clean["estimator_params"].isna()
            ls_clean = clean[(clean["estimator"] == BASELINE) & same]["rmse_m"].mean()
            vs_ls = float(mine / ls_clean) if ls_clean == ls_clean and ls_clean > 0 and mine == mine else None
            band = bands.get(stem, {}).get(label)
            verdict = "" if band is None or mean is None else ("in band" if band[0] <= mean <= band[1] else "OUT")
            rows.append({
                "study": stem, "method": label, "origin": f"{dist} {version_}" if isinstance(dist, str) else "",
                "n": n, "rmse_m": mean, "rmse_lo": lo, "rmse_hi": hi,
                "valid_fraction": g["valid_fraction"].mean(), "recall": g["attack_detection_recall"].mean(),
                "own_recall": g["own_recall_all"].mean() if "own_recall_all" in g else None,
                "false_alarm_rate": g["false_alarm_rate"].mean(),
                "cell_wall_s": float(frame.drop_duplicates("cell")["wall_s"].median()),
                "step_us": g["step_time_us_median"].median(),
                "clean_vs_ls": vs_ls, "worse_than_ls": bool(secure.get(label) and vs_ls is not None and vs_ls > 1),
                "band": "" if band is None else f"{band[0]:.3f}-{band[1]:.3f}", "check": verdict,
                "failed": int((frame[frame["estimator"] == label]["status"] != "ok").sum()),
            })  # fmt: skip
    board = pd.DataFrame(rows)
    if len(board):
        board = board.sort_values(["study", "rmse_m"], kind="stable").reset_index(drop=True)
    head = f"SecUAV suite v{meta['suite']} ({meta['variant']})"
    return board, [head, *sorted(prov)]


def plugin_code(rows: pd.DataFrame) -> set[str]:
    """A provenance line per plugin estimator and primitive that computed ``rows``: its distribution, version and
    source hash (the built-ins are pinned by the secuav commit)."""
    out = set()
    cols = ["estimator_name", "estimator_dist", "estimator_version", "estimator_code"]
    if all(c in rows for c in cols):
        for name, dist, version, code in rows[cols].drop_duplicates().itertuples(index=False):
            if isinstance(dist, str) and dist and dist != "secuav":
                out.add(f"plugin estimator {name} from {dist} {version}, code {code}")
    for text in rows["primitives"].dropna().unique() if "primitives" in rows else []:
        for kind, where in json.loads(text).items():
            if where.get("dist") and where["dist"] != "secuav":
                out.add(f"plugin primitive {kind} from {where['dist']} {where['version']}, code {where['code']}")
    return out


def _num(v: Any, digits: int = 3) -> str:
    return "" if v is None or v != v else f"{v:.{digits}f}"


def markdown(board: pd.DataFrame, provenance: list[str]) -> str:
    lines = [f"# {provenance[0]}", "", *(f"- computed by: {p}" for p in provenance[1:]), ""]
    cols = ["method", "from", "n", "RMSE [m] mean [95% CI]", "clean RMSE / LS", "valid", "own recall",
            "attribution recall", "false alarms", "cell [s]", "step [us]", "expected band", "check"]  # fmt: skip
    for study, g in board.groupby("study", sort=False):
        lines += [f"## {study}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in g.itertuples(index=False):
            ci = f"{_num(r.rmse_m)} [{_num(r.rmse_lo)}, {_num(r.rmse_hi)}]"
            vs = _num(r.clean_vs_ls, 2) or "n/a"
            vs += " **worse than LS**" if r.worse_than_ls else ""
            lines.append(f"| {r.method} | {r.origin} | {r.n} | {ci} | {vs} | "
                         f"{_num(r.valid_fraction, 2)} | {_num(r.own_recall, 2)} | {_num(r.recall, 2)} | "
                         f"{_num(r.false_alarm_rate, 3)} | "
                         f"{_num(r.cell_wall_s, 1)} | {_num(r.step_us, 0)} | {r.band} | {r.check} |")  # fmt: skip
        lines.append("")
    lines.append("clean RMSE / LS: a method's mean RMSE on the study's clean runs over the undefended snapshot "
                 "least-squares fix's (ls, run in every offline study); a secure method above 1 is marked.")
    return "\n".join(lines)


BAND_LOW, BAND_HIGH = 0.8, 1.25  # a band is the measured mean RMSE x [0.8, 1.25], widened by 5 mm each way


def record_bands(out: Path, version: str = LATEST) -> Path:
    """Write ``expected-<variant>.yaml`` from the built-ins' rows in ``out`` (a maintainer's step, after a
    measured run; the file says which run)."""
    board, provenance = leaderboard(out, version)
    meta = json.loads((out / "suite.json").read_text(encoding="utf-8"))
    builtin = board[board["origin"].str.startswith("secuav ") & ~board["method"].str.contains(r"\[")]
    bands: dict[str, dict[str, list[float]]] = {}
    for r in builtin.itertuples(index=False):
        if r.rmse_m is None or r.rmse_m != r.rmse_m:
            continue
        lo, hi = max(0.0, r.rmse_m * BAND_LOW - 0.005), r.rmse_m * BAND_HIGH + 0.005
        bands.setdefault(r.study, {})[r.method] = [round(lo, 3), round(hi, 3)]
    path = SUITES / version / f"expected-{meta['variant']}.yaml"
    head = (f"# Expected mean RMSE [m] of the built-in estimators, SecUAV suite {version} ({meta['variant']}).\n"
            f"# Measured: `secuav-study suite run{' --quick' if meta['variant'] == 'quick' else ''}` then "
            f"`suite check --record-bands`, rows by\n"
            f"# {'; '.join(provenance[1:])}.\n"
            f"# Band = measured mean x [{BAND_LOW}, {BAND_HIGH}], widened by 5 mm: the rows are deterministic for\n"
            f"# one code version (seeded flights), so leaving a band means the estimator's or the bench's code\n"
            f"# changed what it computes.\n")  # fmt: skip
    path.write_text(head + yaml.safe_dump({"bands": bands}, sort_keys=False), encoding="utf-8")
    return path


def check(out: Path, version: str = LATEST) -> int:
    """Write ``OUT/leaderboard.md`` and ``.csv``, print the Markdown; 1 when a built-in left its band."""
    if not (out / "suite.json").is_file():
        raise InputError(str(out), "suite.json", None, "missing: not a suite output (secuav-study suite run)")
    board, provenance = leaderboard(out, version)
    text = markdown(board, provenance)
    (out / "leaderboard.md").write_text(text + "\n", encoding="utf-8")
    board.assign(provenance=" / ".join(provenance)).to_csv(out / "leaderboard.csv", index=False)
    print(text)
    outside = board[board["check"] == "OUT"] if len(board) else board
    for r in outside.itertuples(index=False):
        print(f"suite check: {r.study} {r.method}: RMSE {_num(r.rmse_m)} outside its expected band {r.band}")
    return 1 if len(outside) else 0

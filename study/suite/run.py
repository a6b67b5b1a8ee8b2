"""``secuav-study suite list|run|check``: the versioned benchmark suite (docs/bench.md).

A suite version is a folder ``study/suite/vN/``: ``suite.yaml`` (the version, the tuning budget, the study files in
order, each one's quick overrides and its tuning split's anchor layout and hover points), the study files and the
tuning split's layouts (``layouts/``). ``run`` writes one study directory per study file under ``OUT`` (the tuning
split, ``--split tuning``: under ``OUT/tuning/``; ``OUT/suite.json`` says which version and variant, what was
added, what was chosen, which layout each split flew), adding the methods under test (``--add huber``, ``--add
'{name: huber, params: {huber_k: [1.0, 1.345]}}'``) to every offline study whose scenario they run on. Every point
a method is run at in ``OUT``, on either split, is charged to its tuning budget (``OUT/budget.json``); on the
evaluation split a method given with a grid runs only at its best point on the tuning split. ``check`` reads
``OUT`` and prints the leaderboard, per split, study and method variant (a secure method's own output and its
``+attribution`` row): mean RMSE with its 95 % bootstrap CI, the valid fraction, detection (the method's own naming
and the attribution's, one definition), where the parameters were tuned, the median wall time of a cell and the
method's step time; each built-in's mean on the evaluation split is compared with its expected band
(``expected-quick.yaml``, ``expected-full.yaml``: measured, see there), and the provenance lines say what computed
the rows and the budget each method used.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from secuav_common.loading import InputError
from study.launch import SMOKE_ENV, smoke  # docs/bench.md: cuts every study to try the commands, never a score

SUITES = Path(__file__).resolve().parent
LATEST = "v1"


SPLITS = ("evaluation", "tuning")
LAYOUTS_LINE = "anchor layouts"  # the leaderboard's provenance lines naming each split's layouts start so
READINGS_LINE = "recorded readings"  # ... and those saying how a study's recorded ranges were taken


@dataclass(frozen=True)
class Entry:
    file: str
    quick: dict[str, Any] | None
    tuning: dict[str, Any] | None = None  # the tuning split's overrides (positions); None: no tuning split


def manifest(version: str = LATEST) -> tuple[dict[str, Any], list[Entry]]:
    folder = SUITES / version
    if not (folder / "suite.yaml").is_file():
        have = ", ".join(sorted(p.name for p in SUITES.glob("v*")))
        raise InputError("--version", "", version, f"no such suite (have: {have})")
    doc = yaml.safe_load((folder / "suite.yaml").read_text(encoding="utf-8"))
    return doc, [Entry(s["file"], s.get("quick"), s.get("tuning")) for s in doc["studies"]]


def study_doc(version: str, entry: Entry, quick: bool, split: str = "evaluation") -> dict[str, Any] | None:
    """The study document as this variant and split run it (None: not in this variant or split). The tuning
    split: the same attacks and durations, seeds from the suite's ``tuning_seed0`` on (as many as the
    evaluation split has) and the hover points of the entry's ``tuning``, so the splits share no flight."""
    doc = yaml.safe_load((SUITES / version / entry.file).read_text(encoding="utf-8"))
    if quick:
        if entry.quick is None:
            return None
        doc.update(entry.quick)
    if split == "tuning":
        if entry.tuning is None:
            return None
        head, _ = manifest(version)
        seeds = doc["seeds"]
        count = seeds if isinstance(seeds, int) else len(seeds)
        overrides = {k: v for k, v in entry.tuning.items() if k != "layout"}
        doc.update(overrides, name=f"{doc['name']}-tuning", scenario=tuning_layout(version, entry),
                   seeds=[int(head["tuning_seed0"]) + i for i in range(count)])  # fmt: skip
    return doc


def tuning_layout(version: str, entry: Entry) -> str:
    """The entry's tuning-split scenario: a layout file of the suite version (``layouts/``, relative to it), the
    evaluation scenario with its anchors moved, so that the splits share no anchor layout."""
    layout = (entry.tuning or {}).get("layout")
    if not isinstance(layout, str) or not (SUITES / version / layout).is_file():
        raise InputError(str(SUITES / version / "suite.yaml"), f"{entry.file}: tuning.layout", layout,
                         "a tuning split needs a layout file of its own (layouts/...yaml in the suite folder): "
                         "the splits must not share anchor layouts")  # fmt: skip
    return layout


def _scenario_path(version: str, ref: str) -> str:
    """A study's scenario as the suite's files name it: a file of the suite folder (a tuning layout), else as given
    (a bundled or plugin scenario's name)."""
    near = SUITES / version / ref
    return str(near) if near.is_file() else ref


def layouts(version: str, entries: list[Entry], quick: bool, split: str) -> dict[str, dict[str, str]]:
    """Per study of this split: the scenario (anchor layout) it flies, by name and content hash (the hash a cell
    key is made of), for ``OUT/suite.json`` and the leaderboard's provenance."""
    import hashlib

    from secuav_common.loading import dump_json
    from secuav_common.scenario import load_scenario, resolve_scenario_path

    out: dict[str, dict[str, str]] = {}
    for entry in entries:
        doc = study_doc(version, entry, quick, split)
        if doc is None:
            continue
        scenario = load_scenario(resolve_scenario_path(_scenario_path(version, doc["scenario"])))
        digest = hashlib.sha256(dump_json(scenario).encode()).hexdigest()[:16]
        out[Path(entry.file).stem] = {"scenario": scenario.name, "file": str(doc["scenario"]), "hash": digest}
    return out


def list_text(version: str = LATEST) -> str:
    from study.spec import expand, parse_study

    head, entries = manifest(version)
    lines = [f"SecUAV suite v{head['version']} (tuning budget {head['tuning_budget']} points per method, counted per "
             "OUT over both splits)",
             f"{'study':<28} {'quick cells':>11} {'full cells':>10} {'tuning quick/full':>17}  "
             "scenario / mode"]  # fmt: skip
    for entry in entries:
        counts = []
        for split, quick in (("evaluation", True), ("evaluation", False), ("tuning", True), ("tuning", False)):
            doc = study_doc(version, entry, quick, split)
            if doc is None:
                counts.append("-")
                continue
            source = str(SUITES / version / entry.file)
            counts.append(str(len(expand(parse_study(yaml.safe_dump(doc), source), source))))
        full = study_doc(version, entry, False) or {}
        lines.append(f"{Path(entry.file).stem:<28} {counts[0]:>11} {counts[1]:>10} {counts[2] + '/' + counts[3]:>17}  "
                     f"{full.get('scenario')} / {full.get('mode', 'offline')}")  # fmt: skip
    return "\n".join(lines)


def _with_added(doc: dict[str, Any], added: list[Any], budget: int, version: str) -> tuple[dict[str, Any], list[str]]:
    """The study with the methods under test appended where they run; and the names left out (with why)."""
    import estimators
    from estimators.scenario_models import model_for
    from secuav_common.scenario import load_scenario, resolve_scenario_path

    doc = {**doc, "tuning_budget": budget}
    if doc.get("mode", "offline") != "offline" or not added:
        return doc, []
    model = model_for(load_scenario(resolve_scenario_path(_scenario_path(version, doc["scenario"]))),
                      int(doc.get("dims", 3)))  # fmt: skip
    keep, skipped = list(doc["estimators"]), []
    for entry in added:
        name = entry if isinstance(entry, str) else entry["name"]
        if estimators.registry.get(name).applies_to(model):
            keep.append(entry)
        else:
            skipped.append(f"{name} (does not run on {doc['scenario']})")
    return {**doc, "estimators": keep}, skipped


def _entry_points(entry: Any) -> tuple[str, list[dict[str, Any]]]:
    """A method under test: its name and every point of its own grid (``ValueError`` on a bad entry)."""
    from study.spec import EstimatorSpec, _grid

    if isinstance(entry, str):
        return entry, [{}]
    if not isinstance(entry, dict):
        raise ValueError(f"--add {entry!r}: a name or {{name: ..., params: {{...}}}}")
    spec = EstimatorSpec.model_validate(entry)
    return spec.name, _grid(spec.params, set())


def _point_key(point: dict[str, Any]) -> str:
    return json.dumps(point, sort_keys=True, separators=(",", ":"))


BUDGET_FILE = "budget.json"


def ledger(out: Path) -> dict[str, Any]:
    """``OUT/budget.json``: per method under test, every parameter point any command ran in OUT (either split)."""
    path = out / BUDGET_FILE
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {"methods": {}}


def _charge(out: Path, added: list[Any], budget: int, split: str) -> None:
    """Count this command's points into OUT's ledger; refuse (nothing run) when a method would pass the budget."""
    book = ledger(out)
    methods = book.setdefault("methods", {})
    for entry in added:
        name, points = _entry_points(entry)
        had = methods.get(name, {}).get("points", [])
        total = list(dict.fromkeys([*had, *(_point_key(p) for p in points)]))
        if len(total) > budget:
            raise InputError(str(out / BUDGET_FILE), name, len(total),
                             f"{len(total)} parameter points of {name} in this directory ({len(had)} run before, "
                             f"over both splits) exceed the suite's tuning budget of {budget}")  # fmt: skip
        methods[name] = {"points": total, "splits": sorted({*methods.get(name, {}).get("splits", []), split})}
    book["budget"] = budget
    (out / BUDGET_FILE).write_text(json.dumps(book, indent=2, sort_keys=True) + "\n", encoding="utf-8")


def best_points(out: Path, added: list[Any], version: str, before: dict[str, Any] | None = None,
                ) -> tuple[list[Any], dict[str, Any]]:  # fmt: skip
    """The evaluation split's entries: a method given with a grid runs at its one point of least mean RMSE over
    OUT's tuning split (its own output's rows; every point must have been run there), others as given; and what
    was chosen, per method (point, how many points, the tuning RMSE of each). A choice made before in OUT for
    the same grid (``before``) stands: the evaluation split of one directory has one point per method, so a
    later tuning command cannot change which evaluation rows are the method's."""
    from study import store
    from study.spec import variant_label

    _, entries = manifest(version)
    resolved: list[Any] = []
    chosen: dict[str, Any] = {}
    for entry in added:
        name, points = _entry_points(entry)
        if len(points) == 1:
            resolved.append(entry)
            continue
        labels = {variant_label(name, p): p for p in points}
        held = (before or {}).get(name)
        if held is not None and set(held["tuning_rmse_m"]) == set(labels):
            resolved.append({"name": name, "params": held["point"]} if held["point"] else name)
            chosen[name] = held
            continue
        frames = [store.load(out / "tuning" / Path(e.file).stem) for e in entries]
        rows = pd.concat([f for f in frames if len(f)], ignore_index=True) if any(len(f) for f in frames) else None
        scores: dict[str, float] = {}
        for label in labels:
            mine = None if rows is None else rows[(rows["estimator"] == label) & (rows["status"] == "ok")]
            if mine is None or not len(mine):
                raise InputError(str(out / "tuning"), "estimator", label,
                                 "no tuning-split rows for this point: run `secuav-study suite run --split "
                                 "tuning` with the same --add first; the evaluation split runs only the best "
                                 "point")  # fmt: skip
            scores[label] = float(mine["rmse_m"].mean())
        best = min(scores, key=lambda k: scores[k])
        point = labels[best]
        resolved.append({"name": name, "params": point} if point else name)
        scored = {k: round(v, 6) for k, v in scores.items()}
        chosen[name] = {"point": point, "label": best, "of": len(points), "tuning_rmse_m": scored}
    return resolved, chosen


def run(out: Path, *, quick: bool, version: str, added: list[Any], only: list[str] | None = None,
        workers: int | None = None, scheduler: str | None = None, ports: int | None = None, progress: bool = True,
        split: str = "evaluation") -> int:  # fmt: skip
    """Run every study of the suite (or those in ``only``) of one split into ``out/<study>`` (the tuning split:
    ``out/tuning/<study>``); the worst exit code. Every method under test is charged to OUT's tuning budget.

    Each study runs as ``secuav-study run`` runs it (:func:`study.launch.run_study`), with these workers,
    scheduler and progress bars."""
    from study.launch import run_study

    head, entries = manifest(version)
    if split not in SPLITS:
        raise InputError("--split", "", split, f"one of {', '.join(SPLITS)}")
    stems = [Path(e.file).stem for e in entries]
    for name in only or []:
        if name not in stems:
            raise InputError("--only", "", name, f"not a study of suite {version} ({', '.join(stems)})")
    for entry in added:
        try:
            _entry_points(entry)
        except ValueError as exc:
            raise InputError("--add", "", entry, str(exc).splitlines()[0]) from None
    names = [_entry_points(e)[0] for e in added]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError("--add", "", twice[0], "given twice: one --add per method, with a list in params to sweep "
                         "(--add '{name: huber, params: {huber_k: [1.0, 2.0]}}')")  # fmt: skip
    if only:
        entries = [e for e in entries if Path(e.file).stem in only]
    out.mkdir(parents=True, exist_ok=True)
    held = out / "suite.json"
    meta = json.loads(held.read_text()) if held.is_file() else {}
    variant = "quick" if quick else "full"
    for key, want in (("variant", variant), ("smoke", smoke())):
        if meta and meta.get(key, False) != want:
            raise InputError(str(out), f"suite.json: {key}", meta.get(key, False),
                             f"this directory holds another run ({key} {meta.get(key, False)}); "
                             "use a new OUT")  # fmt: skip
    chosen: dict[str, Any] = {}
    if split == "evaluation":
        before = meta.get("splits", {}).get("evaluation", {}).get("chosen", {})
        added, chosen = best_points(out, added, version, before)
    _charge(out, added, int(head["tuning_budget"]), split)
    splits = meta.get("splits", {})
    splits[split] = {"added": added, **({"chosen": chosen} if split == "evaluation" else {}),
                     "layouts": {**splits.get(split, {}).get("layouts", {}), **layouts(version, entries, quick, split)}}
    meta = {"suite": head["version"], "variant": variant, "smoke": smoke(), "added": added, "splits": splits}
    held.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    for name, c in chosen.items():
        print(f"suite: {name}: best of {c['of']} points on the tuning split: {c['label']}", flush=True)
    worst = 0
    for entry in entries:
        doc = study_doc(version, entry, quick, split)
        if doc is None:
            print(f"suite: {entry.file}: not in the {'quick variant' if quick else f'{split} split'}", flush=True)
            continue
        if smoke() and doc.get("mode", "offline") != "offline":
            print(f"suite: {entry.file}: real-time flights are not in a smoke run ({SMOKE_ENV})", flush=True)
            continue
        doc, skipped = _with_added(doc, added, int(head["tuning_budget"]), version)
        for s in skipped:
            print(f"suite: {entry.file}: {s}", flush=True)
        stem = Path(entry.file).stem
        where = out / stem if split == "evaluation" else out / "tuning" / stem
        path = out / "studies" / f"{stem}{'' if split == 'evaluation' else '-tuning'}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        if split == "tuning":  # its layout file beside it, under the same relative name (OUT stays whole)
            layout = path.parent / doc["scenario"]
            layout.parent.mkdir(parents=True, exist_ok=True)
            layout.write_bytes((SUITES / version / doc["scenario"]).read_bytes())
        path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
        print(f"suite: {stem} ({split} split)", flush=True)
        code = run_study(path, where, workers=workers, scheduler=scheduler, ports=ports, progress=progress)
        if code == 130:  # interrupted: stop here; run again to go on (done cells are skipped)
            return code
        if code == 2:  # bad input: the same for every study, so said once
            return code
        worst = max(worst, code)
    return worst


def _expected(version: str, variant: str) -> dict[str, dict[str, list[float]]]:
    path = SUITES / version / f"expected-{variant}.yaml"
    if not path.is_file():
        return {}
    doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    return doc.get("bands", {})


DETECTION_COLUMNS = tuple(f"{who}_{figure}" for who in ("own", "attribution")
                          for figure in ("recall", "precision", "false_naming"))  # fmt: skip


def _tuned_on(name: Any, label: str, chosen: dict[str, Any], split: str) -> str:
    """Where a row's parameters were chosen: the suite's tuning split (a method given with a grid), else what
    the class declares (``Estimator.tuned_on``; the built-ins: docs/bench.md, "Tuning")."""
    import estimators

    pick = chosen.get(name) if isinstance(name, str) else None
    point = label.split("+")[0]
    if pick is not None and split == "evaluation" and point == pick["label"]:
        return f"tuning split: best of {pick['of']} points"
    if "[" in point:  # parameters of its own: a point of a grid, or one given as it is
        return "a tuning point" if split == "tuning" else "as given (--add)"
    try:
        declared = estimators.registry.get(name).tuned_on if isinstance(name, str) else ""
    except (ValueError, ImportError):
        declared = ""
    return declared or "not declared"


def leaderboard(out: Path, version: str = LATEST) -> tuple[pd.DataFrame, list[str]]:
    """One row per (study, split, method variant) over ``out``; and the provenance lines."""
    from study import store
    from study.report import BASELINE, mean_ci, readings, secure_names

    meta = json.loads((out / "suite.json").read_text(encoding="utf-8"))
    bands = {} if meta.get("smoke") else _expected(version, meta["variant"])
    chosen = meta.get("splits", {}).get("evaluation", {}).get("chosen", {})
    rows: list[dict[str, Any]] = []
    prov: set[str] = set()
    _, entries = manifest(version)
    for split in SPLITS:
        for entry in entries:
            stem = Path(entry.file).stem
            frame = store.load(out / stem if split == "evaluation" else out / "tuning" / stem)
            if not len(frame):
                continue
            rows += _study_rows(frame, stem, split, bands if split == "evaluation" else {}, chosen, prov,
                                BASELINE, mean_ci, secure_names)  # fmt: skip
            taken = readings(frame[frame["status"] == "ok"])
            if taken:
                prov.add(f"{READINGS_LINE}, {split} split: {stem}: {'; '.join(taken)}")
    board = pd.DataFrame(rows)
    if len(board):
        order = {s: i for i, s in enumerate(SPLITS)}
        board = board.assign(_split=board["split"].map(order)).sort_values(["_split", "study", "rmse_m"],
                                                                          kind="stable")  # fmt: skip
        board = board.drop(columns="_split").reset_index(drop=True)
    head = f"SecUAV suite v{meta['suite']} ({meta['variant']}{', smoke: not a score' if meta.get('smoke') else ''})"
    book = ledger(out)
    used = "; ".join(f"{name} {len(m['points'])} (splits: {', '.join(m['splits'])})"
                     for name, m in sorted(book.get("methods", {}).items()))  # fmt: skip
    budget = f"tuning budget {book.get('budget', '?')} points per method in this directory; used: {used or 'none'}"
    return board, [head, budget, *_layout_lines(board, meta), *sorted(prov)]


def _layout_lines(board: pd.DataFrame, meta: dict[str, Any]) -> list[str]:
    """Per split, the anchor layout (scenario) each study's rows were flown on, as the rows say, with the content
    hash ``suite run`` recorded for it (``OUT/suite.json``)."""
    lines = []
    for split in SPLITS:
        mine = board[board["split"] == split].drop_duplicates("study") if len(board) else board
        recorded = meta.get("splits", {}).get(split, {}).get("layouts", {})
        parts = []
        for r in mine.itertuples(index=False):
            held = recorded.get(r.study, {})
            digest = held.get("hash") if held.get("scenario") == r.layout else None  # the rows' layout, as recorded
            parts.append(f"{r.study} {r.layout}" + (f" ({digest})" if digest else ""))
        if parts:
            lines.append(f"{LAYOUTS_LINE}, {split} split: {'; '.join(parts)}")
    return lines


def _study_rows(frame: pd.DataFrame, stem: str, split: str, bands: dict[str, Any], chosen: dict[str, Any],
                prov: set[str], baseline: str, mean_ci: Any, secure_names: Any) -> list[dict[str, Any]]:  # fmt: skip
    ok = frame[frame["status"] == "ok"]
    for col in ("secuav_version", "secuav_commit", "secuav_dirty", "python_version", "numpy_version",
                "scipy_version", "output", "processing", *DETECTION_COLUMNS):  # fmt: skip
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
    out = []
    for (label, name, dist, version_), g in ok.groupby(["estimator", "estimator_name", "estimator_dist",
                                                          "estimator_version"], dropna=False, sort=False):  # fmt: skip
        mean, lo, hi, n = mean_ci(g["rmse_m"])
        mine = clean[clean["estimator"] == label]["rmse_m"].mean()
        # The baseline at the same grid point of the study's estimator_params (rows of one grid point only).
        tuning = g["estimator_params"].dropna().unique() if "estimator_params" in g else []
        same = clean["estimator_params"].isin(tuning) if len(tuning) else clean["estimator_params"].isna()
        ls_clean = clean[(clean["estimator"] == baseline) & same]["rmse_m"].mean()
        vs_ls = float(mine / ls_clean) if ls_clean == ls_clean and ls_clean > 0 and mine == mine else None
        band = bands.get(stem, {}).get(label)
        verdict = "" if band is None or mean is None else ("in band" if band[0] <= mean <= band[1] else "OUT")
        output = g["output"].dropna()
        out.append({
            "study": stem, "split": split, "method": label,
            "layout": ", ".join(sorted(ok["scenario"].dropna().unique())),  # the anchor layout the rows flew
            "output": output.iloc[0] if len(output) else ("attributed" if "+attribution" in label else "own"),
            # how it took the readings (the rows' processing: synchronous for flights, framed by construction)
            "processing": ", ".join(sorted(set(g["processing"].dropna()))),
            "origin": f"{dist} {version_}" if isinstance(dist, str) else "",
            "tuned_on": _tuned_on(name, label, chosen, split),
            "n": n, "rmse_m": mean, "rmse_lo": lo, "rmse_hi": hi,
            "valid_fraction": g["valid_fraction"].mean(),
            **{c: g[c].astype(float).mean() for c in DETECTION_COLUMNS},
            "cell_wall_s": float(frame.drop_duplicates("cell")["wall_s"].median()),
            "step_us": g["step_time_us_median"].median(),
            "clean_vs_ls": vs_ls, "worse_than_ls": bool(secure.get(label) and vs_ls is not None and vs_ls > 1),
            "band": "" if band is None else f"{band[0]:.3f}-{band[1]:.3f}", "check": verdict,
            "failed": int((frame[frame["estimator"] == label]["status"] != "ok").sum()),
        })  # fmt: skip
    return out


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
    lines = [f"# {provenance[0]}", "", f"- {provenance[1]}",
             *(f"- {p}" if p.startswith((LAYOUTS_LINE, READINGS_LINE)) else f"- computed by: {p}"
               for p in provenance[2:]), ""]  # fmt: skip
    cols = ["method", "output", "from", "tuned on", "n", "RMSE [m] mean [95% CI]", "clean RMSE / LS", "valid",
            *DETECTION_COLUMNS, "cell [s]", "step [us]", "expected band", "check"]  # fmt: skip
    for (split, study), g in board.groupby(["split", "study"], sort=False):
        lines += [f"## {study} ({split} split)", "", f"Anchor layout (scenario): {g['layout'].iloc[0]}", "",
                  "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in g.itertuples(index=False):
            ci = f"{_num(r.rmse_m)} [{_num(r.rmse_lo)}, {_num(r.rmse_hi)}]"
            vs = _num(r.clean_vs_ls, 2) or "n/a"
            vs += " **worse than LS**" if r.worse_than_ls else ""
            detection = " | ".join(_num(getattr(r, c), 2) for c in DETECTION_COLUMNS)
            lines.append(f"| {r.method} | {r.output} | {r.origin} | {r.tuned_on} | {r.n} | {ci} | {vs} | "
                         f"{_num(r.valid_fraction, 2)} | {detection} | "
                         f"{_num(r.cell_wall_s, 1)} | {_num(r.step_us, 0)} | {r.band} | {r.check} |")  # fmt: skip
        lines.append("")
    lines += ["clean RMSE / LS: a method's mean RMSE on the study's clean runs over the undefended snapshot "
              "least-squares fix's (ls, run in every offline study); a secure method above 1 is marked.",
              "output: own = the method's own output; attributed = its output with SecUAV's shared attribution "
              "(the +attribution row of a secure method). own_* / attribution_*: recall, precision and false "
              "naming of the method's own naming and of the attribution's (docs/bench.md, \"Detection\"); "
              "empty where there is no such claim.",
              "split: evaluation = the scored cells; tuning = where parameters are chosen (other seeds, anchor "
              "layouts and hover points), never a score."]  # fmt: skip
    return "\n".join(lines)


BAND_LOW, BAND_HIGH = 0.8, 1.25  # a band is the measured mean RMSE x [0.8, 1.25], widened by 5 mm each way


def record_bands(out: Path, version: str = LATEST) -> Path:
    """Write ``expected-<variant>.yaml`` from the built-ins' rows in ``out`` (a maintainer's step, after a
    measured run; the file says which run)."""
    board, provenance = leaderboard(out, version)
    meta = json.loads((out / "suite.json").read_text(encoding="utf-8"))
    builtin = board[board["origin"].str.startswith("secuav ") & ~board["method"].str.contains(r"\[")
                    & (board["split"] == "evaluation")]
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

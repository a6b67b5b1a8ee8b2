"""``secuav-study export DIR BUNDLE``: everything another machine needs to reproduce a study's table.

``run`` keeps a self-contained copy of its inputs in ``DIR/inputs/``: the study
file with its references made local (``scenario.yaml``, ``profiles/*.yaml``),
the scenario as validated, and every attack profile's document as read (a
library profile's text, a file's), so that a library or a file that changes
later does not change what the bundle means. The cells of the copy have the
same keys as the original's (a key hashes the scenario's and the resolved
profile's content, never a path), so ``secuav-study run BUNDLE/study.yaml --out
NEW`` computes the same cells, and where the code is the same (compare
``environment.json``), the same rows.

The bundle: ``study.yaml``, ``scenario.yaml``, ``profiles/``, ``environment.json``
(this machine's secuav version, commit and dirty flag, python/numpy/scipy, every
installed distribution and version, the plugins found, and the provenance the
rows recorded), ``results.csv`` and ``results.parquet/`` (the rows, newest per
cell and estimator) and ``report.md``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import yaml

from attack_profiles import library
from attack_profiles.resolve import is_file_ref
from secuav_common import plugins
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario, resolve_scenario_path
from study import provenance, store
from study.spec import AttackSpec, Study, _resolve_near

INPUTS = "inputs"


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def save_inputs(out: Path, study: Study, source: Path) -> None:
    """Copy the study's inputs into ``out/inputs`` with local references (done by every ``run``)."""
    base = source.resolve().parent
    inputs = out / INPUTS
    if inputs.exists():
        shutil.rmtree(inputs)
    scenario = load_scenario(resolve_scenario_path(_resolve_near(study.scenario, base)))
    _write(inputs / "scenario.yaml", yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False))
    attacks: list[Any] = []
    taken: dict[str, str] = {}
    for entry in study.attacks:
        if not isinstance(entry, AttackSpec):
            attacks.append(entry)
            continue
        ref = _resolve_near(entry.profile, base)
        if is_file_ref(ref):
            text, stem = Path(ref).read_text(encoding="utf-8"), Path(ref).stem
        else:
            text, stem = library.text(ref), ref
        name, n = stem, 1
        while name in taken and taken[name] != text:  # two different files of one name
            n += 1
            name = f"{stem}-{n}"
        taken[name] = text
        _write(inputs / "profiles" / f"{name}.yaml", text)
        attacks.append({"profile": f"profiles/{name}.yaml", **({"params": entry.params} if entry.params else {})})
    doc = study.model_dump(mode="json", exclude_defaults=True)
    doc.update(scenario="scenario.yaml", attacks=attacks)
    _write(inputs / "study.yaml", yaml.safe_dump(doc, sort_keys=False))


def _plugins_found() -> dict[str, list[dict[str, str]]]:
    return {g: [{"name": f.name, "value": f.value, "dist": f.dist, "version": f.version}
                for f in plugins.found(g).values()] for g in plugins.GROUPS}  # fmt: skip


def export(out: Path, bundle: Path) -> Path:
    """Write the bundle of study directory ``out`` to ``bundle`` (a new or empty directory)."""
    inputs = out / INPUTS
    if not (inputs / "study.yaml").is_file():
        raise InputError(str(out), "inputs/study.yaml", None, "missing: run the study with this secuav version first")
    if bundle.exists() and any(bundle.iterdir()):
        raise InputError(str(bundle), "", None, "exists and is not empty; export into a new directory")
    shutil.copytree(inputs, bundle, dirs_exist_ok=True)
    rows = store.load(out)
    cols = ["secuav_version", "secuav_commit", "secuav_dirty", "python_version", "numpy_version", "scipy_version"]
    recorded = rows[[c for c in cols if c in rows]].drop_duplicates().to_dict(orient="records") if len(rows) else []
    code = ["estimator", "estimator_dist", "estimator_version", "estimator_code"]
    env = {
        "exported_by": provenance.environment(),
        "recorded_in_rows": recorded,
        "estimators": rows[code].drop_duplicates().to_dict(orient="records") if len(rows) else [],
        "plugins": _plugins_found(),
        "installed": provenance.installed(),
    }
    (bundle / "environment.json").write_text(json.dumps(env, indent=2, default=str) + "\n", encoding="utf-8")
    rows.to_csv(bundle / "results.csv", index=False)
    (bundle / store.RESULTS).mkdir()
    rows.to_parquet(bundle / store.RESULTS / "part-export.parquet", index=False)
    if (out / "report.md").is_file():
        shutil.copy2(out / "report.md", bundle / "report.md")
    return bundle

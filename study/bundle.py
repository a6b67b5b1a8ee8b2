"""``secuav-study export DIR BUNDLE``: everything another machine needs to reproduce a study's table.

``run`` keeps a self-contained copy of its inputs in ``DIR/inputs/``: the study
file with its references made local (``scenario.yaml``, ``profiles/*.yaml``),
the scenario as validated, every attack profile's document as read (a
library profile's text, a file's) and, for a study on recordings, each
recording's ranges and truth files and its own scenario, so that a library or a
file that changes later does not change what the bundle means. The cells of the copy have the
same keys as the original's (a key hashes the scenario's and the resolved
profile's content, never a path), so ``secuav-study run BUNDLE/study.yaml --out
NEW`` computes the same cells, and where the code is the same (compare
``environment.json``), the same rows.

The bundle: ``study.yaml``, ``scenario.yaml``, ``profiles/``, the recordings' files, ``environment.json``
(this machine's secuav version, commit and dirty flag, python/numpy/scipy, every
installed distribution and version, the plugins found, and the provenance the
rows recorded), ``results.csv`` and ``results.parquet/`` (the rows, newest per
cell and estimator) and ``report.md``. With ``--with-sources`` (or ``--source PATH``), also
``plugins/``: the source of every plugin distribution whose estimator or primitive computed the rows, as an
archive pip installs (``plugins/plugins.json`` lists them); ``secuav-study run BUNDLE/study.yaml`` then installs
those not installed (:func:`install_plugins`) before it reads the study.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
import tomllib
from importlib import metadata
from pathlib import Path
from typing import Any

import yaml

from attack_profiles import library
from attack_profiles.resolve import is_file_ref
from secuav_common import plugins
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario, resolve_scenario_path
from study import provenance, store
from study.spec import AttackSpec, RecordingSpec, Study, _resolve_near

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
    if study.recording is not None:
        doc["recording"] = _save_recording(study.recording, "recording", base, inputs)
    if study.recordings is not None:
        doc["recordings"] = [_save_recording(r, str(r.name), base, inputs) for r in study.recordings]
    _write(inputs / "study.yaml", yaml.safe_dump(doc, sort_keys=False))


# The bundle's own names: a recording's file is never copied over one of them.
OWN = frozenset({"study.yaml", "scenario.yaml", "profiles", "plugins", "environment.json", "results.csv",
                 "results.parquet", "report.md", "recordings"})  # fmt: skip


def _save_recording(spec: RecordingSpec, key: str, base: Path, inputs: Path) -> dict[str, Any]:
    """Copy one recording's files into ``inputs`` and return its entry with the copies' paths.

    Ranges and truth keep the path as written when it is a plain relative one inside the study's folder (an unnamed
    recording's rows show its ranges path as written, and still do); otherwise, and for a name of the bundle's own,
    they go to ``recordings/<key>/ranges.csv`` and ``truth.csv``. Its own scenario is written as validated to
    ``recordings/<key>/scenario.yaml``, as the study's is. The keys of the cells hash the files' content, never
    a path, so the copy computes the same cells."""
    entry = spec.model_dump(mode="json", exclude_defaults=True)
    for role in ("ranges", "truth"):
        written = getattr(spec, role)
        if written is None:
            continue
        parts = Path(written).parts
        inside = not Path(written).is_absolute() and ".." not in parts and parts[0] not in OWN
        target = Path(written) if inside else Path("recordings", key, f"{role}.csv")
        (inputs / target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(_resolve_near(written, base), inputs / target)
        entry[role] = written if inside else target.as_posix()  # inside: the same file from the copy's folder
    if spec.scenario is not None:
        scenario = load_scenario(resolve_scenario_path(_resolve_near(spec.scenario, base)))
        target = Path("recordings", key, "scenario.yaml")
        _write(inputs / target, yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False))
        entry["scenario"] = target.as_posix()
    return entry


def _plugins_found() -> dict[str, list[dict[str, str]]]:
    return {g: [{"name": f.name, "value": f.value, "dist": f.dist, "version": f.version}
                for f in plugins.found(g).values()] for g in plugins.GROUPS}  # fmt: skip


PLUGINS = "plugins"
SKIP = shutil.ignore_patterns(".git", ".venv", "build", "dist", "__pycache__", "*.egg-info", "*.pyc", ".*cache")


def _norm(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


def plugin_dists(rows: Any) -> dict[str, str]:
    """Distribution -> version of every plugin (not secuav) whose estimator or primitive computed ``rows``."""
    out: dict[str, str] = {}
    if not len(rows):
        return out
    for dist, version in rows[["estimator_dist", "estimator_version"]].drop_duplicates().itertuples(index=False):
        if isinstance(dist, str) and dist and dist != "secuav":
            out[dist] = str(version)
    for text in rows["primitives"].dropna().unique():
        for where in json.loads(text).values():
            if where.get("dist") and where["dist"] != "secuav":
                out[where["dist"]] = str(where["version"])
    return out


def installed_source(dist: str) -> Path | None:
    """The local project folder ``dist`` was installed from (PEP 610 ``direct_url.json``), if any."""
    try:
        text = metadata.distribution(dist).read_text("direct_url.json")
    except metadata.PackageNotFoundError:
        return None
    url = json.loads(text).get("url", "") if text else ""
    if not url.startswith("file://"):
        return None
    folder = Path(url.removeprefix("file://"))
    return folder if (folder / "pyproject.toml").is_file() or (folder / "setup.py").is_file() else None


def _project(folder: Path) -> tuple[str, str | None]:
    """(name, static version or None) from a project folder's pyproject.toml."""
    try:
        project = tomllib.loads((folder / "pyproject.toml").read_text(encoding="utf-8")).get("project", {})
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(str(folder), "pyproject.toml", None, f"unreadable: {exc}") from None
    if "name" not in project:
        raise InputError(str(folder), "pyproject.toml: project.name", None, "missing")
    return str(project["name"]), project.get("version")


def _archive(folder: Path, name: str, version: str, into: Path) -> Path:
    """The project folder as ``name-version.tar.gz`` (one top folder, as an sdist), without build or VCS files."""
    stem = f"{_norm(name).replace('-', '_')}-{version}"
    target = into / f"{stem}.tar.gz"
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(folder, Path(tmp) / stem, ignore=SKIP)
        with tarfile.open(target, "w:gz") as tar:
            tar.add(Path(tmp) / stem, arcname=stem)
    return target


def _sources(rows: Any, given: list[Path], bundle: Path) -> list[dict[str, str]]:
    """Copy each plugin's source into ``bundle/plugins``: a ``--source`` folder or archive for it, else the folder
    it was installed from; one line naming the plugin when neither is known."""
    wanted = plugin_dists(rows)
    by_name: dict[str, Path] = {}
    for path in given:
        if path.is_dir():
            name = _project(path)[0]
        elif path.is_file() and path.name.endswith((".tar.gz", ".whl", ".zip")):
            name = path.name.split("-")[0]
        else:
            raise InputError("--source", "", str(path), "expected a project folder, an sdist or a wheel")
        by_name[_norm(name)] = path
    folder = bundle / PLUGINS
    folder.mkdir(parents=True, exist_ok=True)
    listed = []
    for dist, version in sorted(wanted.items()):
        src = by_name.get(_norm(dist)) or installed_source(dist)
        if src is None:
            why = "its source is not known (not installed from a local folder); pass --source PATH"
            raise InputError("--with-sources", "", dist, why)
        if src.is_dir():
            declared = _project(src)[1]
            if declared is not None and declared != version:
                raise InputError(str(src), "pyproject.toml: project.version", declared,
                                 f"the rows were computed by {dist} {version}")  # fmt: skip
            file = _archive(src, dist, version, folder)
        else:
            file = folder / src.name
            shutil.copy2(src, file)
        digest = hashlib.sha256(file.read_bytes()).hexdigest()
        listed.append({"dist": dist, "version": version, "file": file.name, "sha256": digest})
    (folder / "plugins.json").write_text(json.dumps(listed, indent=2) + "\n", encoding="utf-8")
    return listed


def _pip(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", *args],
                          capture_output=True, text=True, check=False, timeout=600)  # fmt: skip


def install_plugins(study: Path) -> list[str]:
    """Install the plugins a bundle ships (``plugins/plugins.json`` beside the study file) that this environment
    lacks; one line per plugin saying what was done. Called by ``run`` before it reads the study."""
    listing = study.resolve().parent / PLUGINS / "plugins.json"
    if not listing.is_file():
        return []
    said = []
    for entry in json.loads(listing.read_text(encoding="utf-8")):
        dist, version, file = entry["dist"], entry["version"], listing.parent / entry["file"]
        try:
            have = metadata.version(dist)
        except metadata.PackageNotFoundError:
            have = None
        if have == version:
            continue
        if have is not None:
            said.append(f"plugin {dist} {have} is installed; the bundle's rows came from {version} "
                        f"(pip install {file} to use the bundle's)")  # fmt: skip
            continue
        if hashlib.sha256(file.read_bytes()).hexdigest() != entry["sha256"]:
            raise InputError(str(file), "sha256", entry["sha256"], "the file does not match plugins.json")
        # Offline first (the build backend of this environment), then with pip's isolated build (needs an index).
        done = _pip(["--no-build-isolation", str(file)])
        if done.returncode != 0:
            done = _pip([str(file)])
        if done.returncode != 0:
            tail = " / ".join(done.stderr.strip().splitlines()[-2:])
            raise InputError(str(file), "", dist, f"pip could not install it: {tail}")
        said.append(f"installed plugin {dist} {version} from {file}")
    if said:
        import importlib

        importlib.invalidate_caches()  # the new distribution's modules and metadata, in this process too
        plugins.found.cache_clear()
        plugins._packages_distributions.cache_clear()
    return said


def _check_recordings(inputs: Path) -> None:
    """Runs before recordings were copied into ``inputs`` left their paths as written: one line, not a bundle
    that cannot run."""
    doc = yaml.safe_load((inputs / "study.yaml").read_text(encoding="utf-8")) or {}
    entries = [doc["recording"]] if doc.get("recording") else list(doc.get("recordings") or [])
    for i, entry in enumerate(entries):
        for role in ("ranges", "truth", "scenario"):
            ref = entry.get(role)
            if ref is not None and (role != "scenario" or is_file_ref(ref)) and not (inputs / ref).is_file():
                field = "recording" if doc.get("recording") else f"recordings[{i}]"
                raise InputError(str(inputs / "study.yaml"), f"{field}.{role}", ref,
                                 "not among the run's inputs: run the study again with this secuav version, "
                                 "which copies recordings there, then export")  # fmt: skip


def export(out: Path, bundle: Path, *, with_sources: bool = False, sources: list[Path] | None = None) -> Path:
    """Write the bundle of study directory ``out`` to ``bundle`` (a new or empty directory); with ``with_sources``
    (or ``sources``) the plugins' sources too."""
    inputs = out / INPUTS
    if not (inputs / "study.yaml").is_file():
        raise InputError(str(out), "inputs/study.yaml", None, "missing: run the study with this secuav version first")
    if bundle.exists() and any(bundle.iterdir()):
        raise InputError(str(bundle), "", None, "exists and is not empty; export into a new directory")
    _check_recordings(inputs)
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
    if with_sources or sources:
        env["plugin_sources"] = _sources(rows, list(sources or []), bundle)
        (bundle / "environment.json").write_text(json.dumps(env, indent=2, default=str) + "\n", encoding="utf-8")
    return bundle

"""Where a result came from: the code that computed it and the environment it ran in.

Every row records the secuav version and git commit (with a dirty flag), the
estimator's and the attack primitives' distribution, version and a hash of
their source (:func:`secuav_common.plugins.source_hash`: the class's module and
its bases'), and the python, numpy and scipy versions. Its ``code_key`` is a
hash of what changes the row's numbers, so that ``secuav-study run`` re-runs
a row whose code changed instead of keeping it: the estimator's source (a new
default changes it), the attack engine's and the primitives' sources, and the
secuav version. The simulator's and the evaluation's code do not enter the key
(every row would re-run after any commit); they are pinned by the commit
recorded beside it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

from attack_profiles.profile import Profile
from secuav_common import plugins
from secuav_common.logs import version as secuav_version

ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def git_state() -> tuple[str | None, bool | None]:
    """(commit, dirty) of the checkout secuav runs from; (None, None) for an installed wheel or without git."""
    if not (ROOT / ".git").exists():
        return None, None
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip() != ""  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None, None
    return head, dirty


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


@functools.cache
def environment() -> dict[str, Any]:
    """The columns every row of this process shares."""
    commit, dirty = git_state()
    return {
        "secuav_version": secuav_version(),
        "secuav_commit": commit,
        "secuav_dirty": dirty,
        "python_version": platform.python_version(),
        "numpy_version": _version("numpy"),
        "scipy_version": _version("scipy"),
    }


def installed() -> dict[str, str]:
    """Every installed distribution and its version (what an export records to rebuild the environment)."""
    out: dict[str, str] = {}
    for dist in metadata.distributions():
        name = dist.metadata["Name"]
        if name:
            out[name] = dist.version
    return dict(sorted(out.items(), key=lambda kv: kv[0].lower()))


@functools.cache
def estimator(name: str) -> dict[str, Any]:
    """Distribution, version and source hash of estimator ``name`` (a built-in, a plugin, or module:Class)."""
    from estimators import registry

    dist, version = registry.origin(name)
    return {"estimator_dist": dist, "estimator_version": version, "estimator_code": registry.code_hash(name)}


def _engine_hash() -> str:
    from attack_profiles.engine import Engine

    return plugins.source_hash(Engine)


def primitives(profile: Profile | None) -> dict[str, dict[str, str]]:
    """kind -> {dist, version, code} of every primitive ``profile`` uses (none for a clean run)."""
    from attack_profiles.primitives import PRIMITIVES, primitive

    out: dict[str, dict[str, str]] = {}
    for rule in [] if profile is None else profile.rules:
        kind = rule.kind  # type: ignore[attr-defined]
        if kind in out:
            continue
        cls = PRIMITIVES.get(kind) or primitive(kind)
        dist, version = plugins.origin(cls)
        out[kind] = {"dist": dist, "version": version, "code": plugins.source_hash(cls) if cls else "missing"}
    return out


def attack_code(profile: Profile | None) -> str:
    """One hash of the engine's and the profile's primitives' sources ("" for a clean run)."""
    if profile is None:
        return ""
    prims = primitives(profile)
    text = json.dumps({"engine": _engine_hash(), **{k: v["code"] for k, v in prims.items()}}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def code_key(estimator_name: str, profile: Profile | None) -> str:
    """What changes a row's numbers besides its cell's definition (see the module docstring)."""
    code = "" if estimator_name == "off" else estimator(estimator_name)["estimator_code"]
    return _key(secuav_version(), code, attack_code(profile))


def _key(version: str, code: str, attack: str) -> str:
    return hashlib.sha256(json.dumps([version, code, attack]).encode()).hexdigest()[:16]


def key_of(estimator_name: str, ident: dict[str, Any]) -> str:
    """The ``code_key`` a row of ``estimator_name`` gets from the code :func:`identity` describes."""
    code = "" if estimator_name == "off" else ident["estimators"].get(estimator_name, "")
    return _key(ident["secuav"], code, ident["attack"])


def identity(names: list[str], profile: Profile | None) -> dict[str, Any]:
    """The code a cell's rows depend on, as this process loaded it: the secuav version, each estimator's source
    hash (built-ins and plugins alike) and the attack code. The client sends its own with every task; a worker
    compares it with this (:func:`differences`) before computing a row (docs/bench.md, "Long-lived workers")."""
    return {
        "secuav": secuav_version(),
        "estimators": {n: _code_or_why(n) for n in sorted(set(names)) if n != "off"},
        "attack": attack_code(profile),
    }


def _code_or_why(name: str) -> str:
    try:
        return str(estimator(name)["estimator_code"])
    except Exception as exc:  # not importable here: a difference to report, not a crash of the worker
        return f"unavailable ({type(exc).__name__}: {exc})"


def differences(loaded: dict[str, Any], expected: dict[str, Any]) -> list[str]:
    """What differs between two :func:`identity` results, one short phrase each ("huber ab12 here, cd34 expected")."""
    out = []
    if loaded.get("secuav") != expected.get("secuav"):
        out.append(f"secuav {loaded.get('secuav')} here, {expected.get('secuav')} expected")
    mine, theirs = loaded.get("estimators", {}), expected.get("estimators", {})
    for name in sorted(set(mine) | set(theirs)):
        if mine.get(name) != theirs.get(name):
            out.append(f"{name} {mine.get(name)} here, {theirs.get(name)} expected")
    if loaded.get("attack") != expected.get("attack"):
        out.append(f"attack code {loaded.get('attack') or '-'} here, {expected.get('attack') or '-'} expected")
    return out


def row_columns(estimator_name: str, profile: Profile | None) -> dict[str, Any]:
    """The provenance columns of one row, computed where the row is computed."""
    if estimator_name == "off":  # a closed-loop flight with the secure stage bypassed: no estimator code
        own: dict[str, Any] = {"estimator_dist": None, "estimator_version": None, "estimator_code": ""}
    else:
        own = estimator(estimator_name)
    return {
        **environment(),
        **own,
        "attack_code": attack_code(profile),
        "primitives": json.dumps(primitives(profile), sort_keys=True, separators=(",", ":")),
        "code_key": code_key(estimator_name, profile),
    }

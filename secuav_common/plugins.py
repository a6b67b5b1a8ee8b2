"""Plugins: estimators, attack primitives, profiles and scenarios from other installed distributions.

A distribution installed beside secuav declares entry points in its own
``pyproject.toml`` (the contract is docs/plugins.md)::

    [project.entry-points."secuav.estimators"]
    huber = "my_bench.huber:Huber"            # an estimators.base.Estimator subclass
    [project.entry-points."secuav.primitives"]
    moving_bias = "my_bench.moving:MovingBias"  # an attack_profiles Primitive; the name is its kind
    [project.entry-points."secuav.profiles"]
    my_bench = "my_bench.profiles"           # a package: every *.yaml in it is a profile
    [project.entry-points."secuav.scenarios"]
    my_bench = "my_bench.scenarios"          # a package: every *.yaml in it is a scenario

Every process finds them by itself, from the installed metadata
(:mod:`importlib.metadata`): the proxy, a Dask worker started without
``--preload``, the console. Discovery reads metadata only; an entry point is
imported when its name is asked for or when a listing is asked for. One that
fails to import is reported once on stderr, in one line naming the plugin and
the error, and is then left out; the built-ins are never affected.

Wherever a name is accepted, ``package.module:Attribute`` is accepted too: it
is imported directly, without any entry point.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, TypeVar

ESTIMATORS = "secuav.estimators"
PRIMITIVES = "secuav.primitives"
PROFILES = "secuav.profiles"
SCENARIOS = "secuav.scenarios"
GROUPS = (ESTIMATORS, PRIMITIVES, PROFILES, SCENARIOS)

_DOTTED = r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*"
_REF = re.compile(rf"^{_DOTTED}:{_DOTTED}$")
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Found:
    """One entry point as the metadata declares it (nothing imported yet)."""

    group: str
    name: str
    value: str  # "package.module:Attribute" or "package"
    dist: str  # the distribution that declares it
    version: str


class PluginError(Exception):
    """A plugin or a ``module:Attribute`` reference that cannot be used; the message says why."""


@functools.cache
def found(group: str) -> dict[str, Found]:
    """The entry points of ``group``, by name, from every installed distribution (metadata only)."""
    out: dict[str, Found] = {}
    for ep in metadata.entry_points(group=group):
        dist = ep.dist
        name = dist.metadata["Name"] if dist is not None else "?"
        version = dist.version if dist is not None else "?"
        if ep.name in out and out[ep.name].dist != name:
            first = out[ep.name]
            _report(group, ep.name, name, f"name also declared by {first.dist} {first.version}; that one is used")
            continue
        out[ep.name] = Found(group, ep.name, ep.value, name, version)
    return out


_loaded: dict[tuple[str, str], Any] = {}
_failed: dict[tuple[str, str], str] = {}


def _report(group: str, name: str, dist: str, error: str) -> None:
    print(f"secuav: plugin {name!r} ({group}, from {dist}) skipped: {error}", file=sys.stderr, flush=True)


def load(group: str, name: str) -> Any | None:
    """The object entry point ``name`` of ``group`` points at; None when there is none or it failed."""
    key = (group, name)
    if key in _loaded:
        return _loaded[key]
    if key in _failed:
        return None
    entry = found(group).get(name)
    if entry is None:
        return None
    try:
        obj = _import(entry.value)
    except Exception as exc:  # a plugin's import may raise anything; it must not take the built-ins down
        _failed[key] = f"{type(exc).__name__}: {exc}"
        _report(group, name, f"{entry.dist} {entry.version}", _failed[key])
        return None
    _loaded[key] = obj
    return obj


def reject(group: str, name: str, reason: str) -> None:
    """Mark a loaded entry point unusable (wrong type, wrong name): reported once, then treated as failed."""
    key = (group, name)
    _loaded.pop(key, None)
    if key not in _failed:
        _failed[key] = reason
        entry = found(group).get(name)
        _report(group, name, "?" if entry is None else f"{entry.dist} {entry.version}", reason)


def failures() -> dict[tuple[str, str], str]:
    """(group, name) -> the error of every plugin that failed to load in this process."""
    return dict(_failed)


def load_all(group: str) -> dict[str, Any]:
    """Every entry point of ``group`` that loads, by name (a listing: imports them all)."""
    out = {}
    for name in found(group):
        obj = load(group, name)
        if obj is not None:
            out[name] = obj
    return out


def lookup(group: str, name: str, check: Callable[[Any, str], T]) -> T | None:
    """The one plugin lookup every registry uses (:class:`secuav_common.registry.Registry`).

    The entry point ``name`` of ``group``, imported now: one that fails to import or to pass ``check`` is
    reported once and left out (None). Else a ``package.module:Attribute`` reference: one that cannot be
    imported or fails ``check`` raises ``PluginError``. Else None. ``check(obj, where)`` returns the part or
    raises ``PluginError``; ``where`` is ``"entry point NAME"`` or the reference.
    """
    if name in found(group):
        obj = load(group, name)
        if obj is None:
            return None
        try:
            return check(obj, f"entry point {name}")
        except PluginError as exc:
            reject(group, name, str(exc))
            return None
    if is_ref(name):
        return check(load_ref(name), name)
    return None


def is_ref(text: str) -> bool:
    """Whether ``text`` is a ``package.module:Attribute`` reference."""
    return bool(_REF.match(text))


def _import(value: str) -> Any:
    module_name, _, attr = value.partition(":")
    obj: Any = importlib.import_module(module_name)
    # Read the module's source now, as it was imported: source_hash then describes the code this process runs
    # even if the file is edited later (a long-lived Dask worker compares it with the client's).
    if isinstance(getattr(obj, "__file__", None), str) and obj.__file__.endswith(".py"):
        _file_bytes(obj.__file__)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj


@functools.cache
def load_ref(ref: str) -> Any:
    """Import ``package.module:Attribute``; ``PluginError`` saying why not."""
    if not is_ref(ref):
        raise PluginError(f"{ref!r} is not of the form package.module:Attribute")
    try:
        return _import(ref)
    except Exception as exc:
        raise PluginError(f"cannot import {ref}: {type(exc).__name__}: {exc}") from None


def origin(obj: Any) -> tuple[str, str]:
    """(distribution, version) that provides ``obj``'s module; ("", "") when none is installed for it."""
    module = getattr(obj, "__module__", None) or getattr(obj, "__name__", "")
    top = module.partition(".")[0]
    dists = _packages_distributions().get(top)
    if not dists:
        return "", ""
    name = dists[0]
    try:
        return name, metadata.version(name)
    except metadata.PackageNotFoundError:
        return name, ""


@functools.cache
def _packages_distributions() -> dict[str, list[str]]:
    return metadata.packages_distributions()


def source_hash(cls: type) -> str:
    """SHA-256 (16 hex) of the source files of ``cls`` and of every base class outside the standard library.

    What a class computes is in its own module and in the modules of its bases
    (the shared estimator base, the primitive base), so a change in any of them
    changes the hash. A class without a readable source hashes its qualified name.
    """
    digest = hashlib.sha256()
    seen: set[str] = set()
    for klass in cls.__mro__:
        if klass is object or klass.__module__ in ("abc", "builtins", "typing"):
            continue
        try:
            path = inspect.getsourcefile(klass)
        except TypeError:
            path = None
        if path is None or path in seen or _in_stdlib(path):
            continue
        seen.add(path)
        digest.update(klass.__module__.encode() + b"\0" + _file_bytes(path))
    if not seen:
        digest.update(f"{cls.__module__}.{cls.__qualname__}".encode())
    return digest.hexdigest()[:16]


@functools.cache
def _file_bytes(path: str) -> bytes:
    return Path(path).read_bytes()


def _in_stdlib(path: str) -> bool:
    stdlib = Path(inspect.getsourcefile(functools) or "").parent
    return Path(path).is_relative_to(stdlib) and "site-packages" not in path


def yaml_files(group: str, name: str) -> dict[str, Path]:
    """The ``*.yaml`` files of the package entry point ``name`` of ``group`` (profiles, scenarios), by stem."""
    package = load(group, name)
    if package is None:
        return {}
    where = getattr(package, "__path__", None)
    if not where:
        reject(group, name, f"{found(group)[name].value} is not a package (a folder of YAML files)")
        return {}
    return {p.stem: p for folder in where for p in sorted(Path(folder).glob("*.yaml"))}


def yaml_catalogue(group: str) -> dict[str, tuple[Path, Found]]:
    """Every YAML file of every package entry point of ``group``: stem -> (file, the entry it came from).

    A stem two plugins both ship is taken from the first, and the other is reported.
    """
    out: dict[str, tuple[Path, Found]] = {}
    for name, entry in found(group).items():
        for stem, path in yaml_files(group, name).items():
            if stem in out:
                _report(group, name, entry.dist, f"{stem}.yaml also shipped by {out[stem][1].dist}; that one is used")
                continue
            out[stem] = (path, entry)
    return out

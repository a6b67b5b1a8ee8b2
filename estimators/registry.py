"""Name -> estimator class, so callers say ``create("secekf", model, s=2)``.

Three kinds of names, tried in this order:

- the built-ins, registered by :mod:`estimators` with :func:`register`;
- plugins: the ``secuav.estimators`` entry points of other installed
  distributions (docs/plugins.md), imported only when their name is asked for
  or a listing (:func:`names`) is;
- ``package.module:Class``: imported directly.

Each estimator's parameters are its constructors' keyword parameters with their
defaults (read from the signatures, so they cannot drift from the code); a class
may add ranges in ``param_ranges`` (``{"huber_k": (0.5, 3.0)}``), and the shared
ones have theirs here. :func:`parameters` gives both and :func:`describe` an
estimator's whole entry, for listings (``secuav-plugins``, the console).
"""

from __future__ import annotations

import inspect
import math
import re
import sys
from dataclasses import dataclass
from typing import Any

from estimators.base import Estimator
from estimators.models import MeasurementModel
from secuav_common import plugins
from secuav_common.registry import Registry

# Ranges of the parameters every estimator shares (estimators.base.Estimator).
SHARED_RANGES: dict[str, tuple[float, float]] = {
    "alpha": (1e-6, 0.5),
    "q_mps2": (0.0, 50.0),
    "p0_pos_m": (0.0, 1e4),
    "p0_vel_mps": (0.0, 1e3),
    "n_iter": (1, 50),
}


def _checked(obj: object, where: str) -> type[Estimator]:
    if not (isinstance(obj, type) and issubclass(obj, Estimator)):
        subject = where if plugins.is_ref(where) else repr(obj)
        raise plugins.PluginError(f"{subject} is not an estimators.base.Estimator subclass")
    return obj


# The built-ins only: a plugin is looked up when asked for, never entered (listings tell them apart by this).
REGISTRY: Registry[type[Estimator]] = Registry("estimator", plugins.ESTIMATORS, _checked)


def register(cls: type[Estimator]) -> type[Estimator]:
    return REGISTRY.register(cls.name, cls)


def lookup(name: str) -> type[Estimator] | None:
    """The class ``name`` stands for (built-in, plugin or ``module:Class``), or None; imports only that one."""
    return REGISTRY.lookup(name)  # PluginError says why a module:Class cannot be used


def get(name: str) -> type[Estimator]:
    """Like :func:`lookup`, but a name that stands for nothing is a ``ValueError`` listing the known ones."""
    try:
        cls = lookup(name)
    except plugins.PluginError as exc:
        raise ValueError(str(exc)) from None
    if cls is None:
        raise ValueError(f"unknown estimator {name!r}; choose one of {', '.join(names())} or package.module:Class")
    return cls


def known(name: str) -> bool:
    """Whether ``name`` stands for an estimator that can be built here."""
    try:
        return lookup(name) is not None
    except plugins.PluginError:
        return False


def builtin_names() -> list[str]:
    """The built-in estimators' names, baselines first (no plugin is looked at)."""
    return REGISTRY.builtin_names()


def names(model: MeasurementModel | None = None) -> list[str]:
    """Estimator names, built-in (baselines first) then plugins; with ``model``, only those that run on it.

    A listing: it imports every plugin estimator (one that fails is reported and left out).
    """
    return [n for n, cls in REGISTRY.load_all().items() if model is None or cls.applies_to(model)]


def create(name: str, model: MeasurementModel, **params: Any) -> Estimator:
    """Build estimator ``name`` on ``model``; ``params`` are its keyword parameters (s, alpha, ...)."""
    return get(name)(model, **params)


@dataclass(frozen=True, slots=True)
class Param:
    """One keyword parameter of an estimator: its default and, where declared, its range."""

    name: str
    default: Any
    low: float | None = None
    high: float | None = None

    def text(self) -> str:
        span = "" if self.low is None else f" in [{self.low:g}, {self.high:g}]"
        return f"{self.name}={self.default!r}{span}"

    def as_json(self) -> dict[str, Any]:
        """``{"default", "low", "high"}`` with JSON values: a default JSON cannot hold is given as its repr,
        an infinite or missing bound as None (unbounded)."""
        return {"default": _plain(self.default), "low": _bound(self.low), "high": _bound(self.high)}


def _bound(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _plain(value: Any) -> Any:
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float) and math.isfinite(value):
        return value
    return repr(value)


def parameters(cls: type[Estimator]) -> list[Param]:
    """The keyword parameters of ``cls``'s constructors, its own first, with defaults and ranges."""
    ranges = {**SHARED_RANGES, **getattr(cls, "param_ranges", {})}
    out: dict[str, Param] = {}
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        for p in inspect.signature(init).parameters.values():
            if p.kind is not inspect.Parameter.KEYWORD_ONLY or p.name in out:
                continue
            low, high = ranges.get(p.name, (None, None))
            default = None if p.default is inspect.Parameter.empty else p.default
            out[p.name] = Param(p.name, default, low, high)
    return list(out.values())


def summary(cls: type[Estimator]) -> str:
    """The first line of ``cls``'s docstring (or, without one, its module's), less a leading label naming it
    (``name``:, `name`:, name:, name - ; the listing prints the name itself)."""
    module = sys.modules.get(cls.__module__)
    text = (cls.__doc__ or getattr(module, "__doc__", None) or "").strip()
    line = text.splitlines()[0] if text else ""
    label = re.match(rf"\s*(``|`|\*\*)?{re.escape(cls.name)}(``|`|\*\*)?\s*(:|-|\u2014)\s*", line)
    return line[label.end() :].strip() if label and cls.name else line


def describe(name: str) -> dict[str, Any]:
    """Estimator ``name`` for a listing, JSON-ready: ``name``, ``dist``, ``version``, ``object``,
    ``summary`` and ``params`` (parameter name -> ``default``, ``low``, ``high``; no range: None)."""
    cls = get(name)
    dist, version = origin(name)
    return {"name": name, "dist": dist, "version": version, "object": f"{cls.__module__}:{cls.__qualname__}",
            "summary": summary(cls), "params": {p.name: p.as_json() for p in parameters(cls)}}  # fmt: skip


def origin(name: str) -> tuple[str, str]:
    """(distribution, version) providing estimator ``name`` ("secuav" and its version for the built-ins)."""
    get(name)  # a ValueError for a name that stands for nothing
    return REGISTRY.origin(name)


def code_hash(name: str) -> str:
    """A hash of the source of estimator ``name`` and its bases: changes when its code or a default does."""
    return plugins.source_hash(get(name))

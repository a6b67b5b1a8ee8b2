"""Name -> estimator class, so callers say ``create("secekf", model, s=2)``."""

from __future__ import annotations

from typing import Any

from estimators.base import Estimator
from estimators.models import MeasurementModel

_REGISTRY: dict[str, type[Estimator]] = {}


def register(cls: type[Estimator]) -> type[Estimator]:
    if not cls.name or cls.name in _REGISTRY:
        raise ValueError(f"estimator name {cls.name!r} missing or taken")
    _REGISTRY[cls.name] = cls
    return cls


def names(model: MeasurementModel | None = None) -> list[str]:
    """Registered estimator names, baselines first; with ``model``, only those that can run on it."""
    return [name for name, cls in _REGISTRY.items() if model is None or cls.applies_to(model)]


def create(name: str, model: MeasurementModel, **params: Any) -> Estimator:
    """Build estimator ``name`` on ``model``; ``params`` are its keyword parameters (s, alpha, ...)."""
    try:
        cls = _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}; choose one of {', '.join(_REGISTRY)}") from None
    return cls(model, **params)

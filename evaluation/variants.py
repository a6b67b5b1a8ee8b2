"""The rows an estimator gets in a comparison table, one definition for ``secuav-eval`` and ``secuav-study``.

A secure method (``secure = True``) has two offline: ``name``, its own output with the shared attribution
switched off (output ``own``), and ``name+attribution``, the same method with the attribution judging its output
(output ``attributed``; estimators.base, ``attribution``). Any other method has one row, its name. Closed loop
flies the secure stage, which always attributes: its one row is ``name+attribution``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import estimators

SECURE_OFF = "off"  # closed loop: fly with the secure stage bypassed
ATTRIBUTED = "+attribution"  # the label suffix of a secure method's row with the shared attribution on its output


@dataclass(frozen=True, slots=True)
class Variant:
    """One estimator at one point of its own parameter grid, with or without the shared attribution on its
    output: what a row's ``estimator`` column names."""

    label: str  # the name, or name[k=v,...] when it has parameters of its own; + "+attribution" when attributed
    name: str
    params: dict[str, Any]  # its own parameters (the grid point)
    # The shared attribution on its output (estimators.base, ``attribution``): None = the class's default
    # (closed loop, where the secure stage always attributes); False for a secure method's own row.
    attribution: bool | None = None

    @property
    def output(self) -> str:
        """What the row scores: ``own`` (the method's own output) or ``attributed`` (with the attribution)."""
        return "attributed" if self.label.endswith(ATTRIBUTED) else "own"

    def build_params(self) -> dict[str, Any]:
        """Its own parameters as the estimator's constructor takes them (the attribution switched off or not)."""
        return self.params if self.attribution is None else {**self.params, "attribution": self.attribution}


def with_attribution(name: str, label: str, params: dict[str, Any], mode: str) -> list[Variant]:
    """A secure method's two rows offline (its own output, then with the shared attribution); one row otherwise.
    Closed loop flies the secure stage, which always attributes: its one row is labelled ``+attribution``."""
    if name == SECURE_OFF or not is_secure(name):
        return [Variant(label, name, params)]
    if mode != "offline":
        return [Variant(label + ATTRIBUTED, name, params)]
    return [Variant(label, name, params, attribution=False), Variant(label + ATTRIBUTED, name, params, True)]


def is_secure(name: str) -> bool:
    try:
        return bool(estimators.registry.get(name).secure)
    except (ValueError, ImportError):
        return False

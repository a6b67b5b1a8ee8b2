"""Ready-made attack profiles, one YAML file each, every one with a one-line description.

``names()`` lists them, ``load(name, **params)`` validates one with its
parameters overridden (e.g. ``load("type-a", links=[11, 14], offset_m=2.0)``),
``describe()`` gives the one-liners ``secuav-attack list`` prints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from attack_profiles.profile import Profile, parse_profile
from secuav_common.loading import InputError, parse_document

LIBRARY_DIR = Path(__file__).resolve().parent


def names() -> list[str]:
    """Names of the bundled profiles, sorted."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.yaml"))


def path(name: str) -> Path:
    """The file of a bundled profile; ``InputError`` if there is none of that name."""
    candidate = LIBRARY_DIR / f"{name}.yaml"
    if "/" in name or "\\" in name or not candidate.is_file():
        raise InputError("library", "name", name, f"no such library profile (have: {', '.join(names())})")
    return candidate


def text(name: str) -> str:
    """The YAML source of a bundled profile, as shipped."""
    return path(name).read_text(encoding="utf-8")


def load(name: str, **params: Any) -> Profile:
    """Validate a bundled profile, with its declared parameters overridden by ``params``."""
    return parse_profile(text(name), f"library:{name}", **params)


def describe() -> list[tuple[str, str]]:
    """(name, one-line description) of every bundled profile."""
    out = []
    for name in names():
        data = parse_document(text(name), f"library:{name}")
        out.append((name, str(data.get("description", "")) if isinstance(data, dict) else ""))
    return out

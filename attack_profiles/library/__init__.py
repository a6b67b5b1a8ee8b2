"""Ready-made attack profiles, one YAML file each, every one with a one-line description.

``names()`` lists them, ``load(name, **params)`` validates one with its
parameters overridden (e.g. ``load("type-a", links=[11, 14], offset_m=2.0)``),
``describe()`` gives the one-liners ``secuav-attack list`` prints.

Installed plugins add theirs: every ``*.yaml`` of a ``secuav.profiles`` entry
point's package is a library profile named by its file (docs/plugins.md). A
bundled name always wins over a plugin's; ``plugins=False`` lists the bundled
ones alone (what the generated docs show).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from attack_profiles.profile import Profile, parse_profile
from secuav_common import plugins as _plugins
from secuav_common.loading import InputError, parse_document

LIBRARY_DIR = Path(__file__).resolve().parent


def _bundled() -> list[str]:
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.yaml"))


def _from_plugins() -> dict[str, tuple[Path, _plugins.Found]]:
    bundled = set(_bundled())
    return {k: v for k, v in _plugins.yaml_catalogue(_plugins.PROFILES).items() if k not in bundled}


def names(plugins: bool = True) -> list[str]:
    """Names of the bundled profiles, sorted, then (with ``plugins``) the installed plugins' profiles, sorted."""
    return _bundled() + (sorted(_from_plugins()) if plugins else [])


def origin(name: str) -> tuple[str, str]:
    """(distribution, version) a library profile comes from; ("secuav", its version) for a bundled one."""
    if (LIBRARY_DIR / f"{name}.yaml").is_file():
        return _plugins.origin(Profile)
    entry = _from_plugins()[name][1]
    return entry.dist, entry.version


def path(name: str) -> Path:
    """The file of a library profile (bundled or a plugin's); ``InputError`` if there is none of that name."""
    candidate = LIBRARY_DIR / f"{name}.yaml"
    if "/" in name or "\\" in name:
        raise InputError("library", "name", name, f"no such library profile (have: {', '.join(names())})")
    if candidate.is_file():
        return candidate
    found = _from_plugins().get(name)
    if found is None:
        raise InputError("library", "name", name, f"no such library profile (have: {', '.join(names())})")
    return found[0]


def text(name: str) -> str:
    """The YAML source of a bundled profile, as shipped."""
    return path(name).read_text(encoding="utf-8")


def load(name: str, **params: Any) -> Profile:
    """Validate a bundled profile, with its declared parameters overridden by ``params``."""
    return parse_profile(text(name), f"library:{name}", **params)


def describe(plugins: bool = True) -> list[tuple[str, str]]:
    """(name, one-line description) of every library profile (``plugins=False``: the bundled ones)."""
    out = []
    for name in names(plugins):
        data = parse_document(text(name), f"library:{name}")
        out.append((name, str(data.get("description", "")) if isinstance(data, dict) else ""))
    return out

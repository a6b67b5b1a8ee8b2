"""What every command means by ``--attack REF`` / ``--profile REF`` and ``--param NAME=VALUE``.

One reading for all of them (secuav-attack, secuav-proxy, secuav-eval,
secuav-record, secuav-demo, secuav-study): ``REF`` is a profile file when that
path exists or ends in .yaml/.yml/.json, otherwise the name of a library
profile; a ``--param`` value is YAML (so JSON too): ``links=[11,14]``,
``offset_m=2``, ``label=text``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from attack_profiles import library
from attack_profiles.profile import Profile, load_profile
from secuav_common.loading import InputError, parse_document

PROFILE_SUFFIXES = (".yaml", ".yml", ".json")


def parse_params(pairs: Iterable[str], flag: str = "--param") -> dict[str, Any]:
    """``["links=[11,14]", "offset_m=2"]`` -> ``{"links": [11, 14], "offset_m": 2}``; ``NAME=`` is null."""
    out: dict[str, Any] = {}
    for pair in pairs:
        name, sep, raw = pair.partition("=")
        if not sep or not name:
            raise InputError(flag, "", pair, "expected NAME=VALUE")
        out[name] = parse_document(raw, f"{flag} {name}") if raw else None
    return out


def is_file_ref(ref: str | Path) -> bool:
    path = Path(ref)
    return path.exists() or path.suffix in PROFILE_SUFFIXES


def resolve_profile(ref: str | Path, params: dict[str, Any] | None = None, flag: str = "--profile") -> Profile:
    """The profile ``ref`` names (a file, else a library name), with ``params`` for its declared parameters."""
    params = params or {}
    if is_file_ref(ref):
        return load_profile(ref, **params)
    name = str(ref)
    if name not in library.names():
        raise InputError(flag, "", name, f"no such file or library profile (library: {', '.join(library.names())})")
    return library.load(name, **params)

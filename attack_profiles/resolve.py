"""What every command means by ``--attack REF`` / ``--profile REF`` and ``--param NAME=VALUE``.

One reading for all of them (secuav-attack, secuav-proxy, secuav-eval,
secuav-record, secuav-demo, secuav-study): ``REF`` is a profile file when that
path exists or ends in .yaml/.yml/.json, otherwise the name of a library
profile; a ``--param`` value is YAML (so JSON too): ``links=[11,14]``,
``offset_m=2``, ``label=text`` (``secuav_common.loading.parse_params``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from attack_profiles import library
from attack_profiles.profile import Profile, load_profile
from secuav_common.loading import InputError
from secuav_common.loading import parse_params as parse_params  # its home; kept here for older importers

PROFILE_SUFFIXES = (".yaml", ".yml", ".json")


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

"""Turn a control-plane payload into a profile (docs/interfaces.md, topic ``secuav/v1/attack/set``).

The topic carries a full profile, ``{"library": "<name>"}`` (optionally with
``"parameters": {...}``), or ``null`` to clear; any of them may carry a
``request_id``, which is the transport's business and ignored here. Pure: the
proxy owns the MQTT side and calls this on the decoded JSON.
"""

from __future__ import annotations

from typing import Any

from attack_profiles import library
from attack_profiles.profile import Profile, parse_profile, parse_text
from secuav_common.loading import InputError


def profile_from_payload(payload: Any, source: str = "<mqtt>") -> Profile | None:
    """``None`` means "clear the active profile"; raises ``InputError`` for anything invalid."""
    if payload is None:
        return None
    if isinstance(payload, dict):
        payload = {k: v for k, v in payload.items() if k != "request_id"}
        if not payload:
            return None
        if "library" in payload:
            extra = set(payload) - {"library", "parameters"}
            if extra:
                raise InputError(source, sorted(extra)[0], payload[sorted(extra)[0]], "not allowed with 'library'")
            name, params = payload["library"], payload.get("parameters") or {}
            if not isinstance(name, str):
                raise InputError(source, "library", name, "must be a library profile name")
            if not isinstance(params, dict):
                raise InputError(source, "parameters", params, "must be a mapping of parameter name to value")
            return library.load(name, **{str(k): v for k, v in params.items()})
    if isinstance(payload, str | bytes):  # profile text inside the message: from the network, so no YAML aliases
        payload = parse_text(payload, source, trusted=False)
    return parse_profile(payload, source)

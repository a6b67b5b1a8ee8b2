"""attack_profiles: typed attack profiles and the one engine that applies them.

A pure library (no sockets, no asyncio): the proxy's attack stage feeds it live
MAVLink messages, the evaluation feeds it arrays of measurements; both read the
same profile files. See docs/profile.md and attack_profiles/README.md.

- :func:`load_profile` / :func:`parse_profile` read and validate a profile;
- :mod:`attack_profiles.library` holds ready-made profiles;
- :class:`Engine` applies one profile (:meth:`Engine.process`, :meth:`Engine.apply_array`).
"""

from __future__ import annotations

from attack_profiles.action import FORWARD, Action
from attack_profiles.engine import Engine
from attack_profiles.profile import Profile, load_profile, parse_profile, profile_json_schema
from mavframe.packet import Direction

__all__ = [
    "FORWARD",
    "Action",
    "Direction",
    "Engine",
    "Profile",
    "load_profile",
    "parse_profile",
    "profile_json_schema",
]

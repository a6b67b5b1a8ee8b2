"""Which way a profile's rules act: toward the ground (downlink) or toward the vehicle (uplink).

A rule's ``target.direction`` (``downlink``, the default; ``uplink``; ``both``)
says which frames it may change: ``downlink`` what the vehicle sends (the ground
station, MAVSDK and the secure stage see the change), ``uplink`` what travels
to the vehicle (a companion's or a ground station's messages: the autopilot
itself is fed the change). A profile touches the union of its rules'
directions; one with no rules touches none.

The wire names (``downlink``, ``uplink``) go in payloads (``directions`` in
``secuav/v<N>/attack/state``); people read the words of :data:`WORDS`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from secuav_common.loading import InputError

if TYPE_CHECKING:
    from attack_profiles.profile import Profile
    from attack_profiles.rule import RuleBase

DOWNLINK, UPLINK = "downlink", "uplink"
ORDER: tuple[str, ...] = (DOWNLINK, UPLINK)
WORDS = {DOWNLINK: "toward the ground", UPLINK: "toward the vehicle"}
_OF_TARGET = {"downlink": (DOWNLINK,), "uplink": (UPLINK,), "both": (DOWNLINK, UPLINK)}
# The deployment switch that forbids every change toward the vehicle, as its flag is spelt.
NO_UPLINK_FLAG = "--no-uplink-attacks"


def rule_directions(rule: RuleBase) -> tuple[str, ...]:
    """The directions one rule acts on, in :data:`ORDER`."""
    return _OF_TARGET[rule.target.direction]


def directions_of(profile: Profile | None) -> list[str]:
    """The directions some rule of ``profile`` acts on, in :data:`ORDER` (empty: no profile, or no rules)."""
    if profile is None:
        return []
    found = {d for rule in profile.rules for d in rule_directions(rule)}
    return [d for d in ORDER if d in found]


def describe(directions: list[str] | tuple[str, ...]) -> str:
    """``toward the ground``, ``toward the vehicle``, ``toward the ground and toward the vehicle`` or
    ``nothing`` (a profile without rules)."""
    words = [WORDS[d] for d in ORDER if d in directions]
    return " and ".join(words) if words else "nothing"


def check_no_uplink(profile: Profile, source: str) -> None:
    """Refuse a profile that would change anything toward the vehicle (the deployment forbids it).

    One ``InputError`` naming the first such rule, its target and its direction.
    """
    for i, rule in enumerate(profile.rules):
        if UPLINK in rule_directions(rule):
            t = rule.target
            what = t.message if t.message is not None else f"quantity {t.quantity}"
            raise InputError(
                source,
                f"rules[{i}].target.direction",
                t.direction,
                f"{rule.kind} on {what} would change frames toward the vehicle, which this proxy forbids "
                f"({NO_UPLINK_FLAG})",
            )

"""What a profile leaves true on the wire, and what the vehicle will report of a lie it was fed.

A rule toward the ground (``direction: downlink``) that rewrites a quantity in
one message leaves the truth in the vehicle's other messages that carry it
(:mod:`attack_profiles.quantities`): a DISTANCE_SENSOR rule while ArduPilot also
sends RANGEFINDER. Each such case is a :class:`Finding`. Whether the twin is
really on the wire depends on the vehicle: flightsim never sends RANGEFINDER,
PX4 does not either. So a finding has two wordings:

- :meth:`Finding.text` with no vehicle known (``secuav-attack validate``): a
  conditional, "... still carries the true value if the vehicle sends it";
- :meth:`Finding.text` with the messages this vehicle was seen sending (the
  proxy): only those carriers, and nothing while none of them was seen.

A rule toward the vehicle (``uplink``) leaves no true twin: the autopilot
consumes the lie and reports it in its own messages (an offboard rangefinder
fed to ArduPilot comes back in its DISTANCE_SENSOR and RANGEFINDER). Such a
rule gets one note (:func:`vehicle_reports`) instead of a warning. A ``both``
rule is judged on its downlink part like a downlink rule, and noted for its
uplink part.

RANGEFINDER carries ArduPilot's primary downward rangefinder, the lowest-id
downward DISTANCE_SENSOR; UWB anchor links (ids from 10, docs/interfaces.md) are
never that sensor, so a rule that picks only such ids leaves no RANGEFINDER twin.
"""

from __future__ import annotations

import re
from collections.abc import Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING

from attack_profiles.directions import DOWNLINK, UPLINK, rule_directions
from attack_profiles.quantities import CARRIERS, COMPONENTS, DEFAULT_COMPONENT, NOT_COVERED, Carrier, carriers_of
from attack_profiles.units import MESSAGES
from secuav_common.sensor_ids import ANCHOR_BASE

if TYPE_CHECKING:
    from attack_profiles.profile import Profile
    from attack_profiles.rule import RuleBase

_MESSAGE_NAME = re.compile(r"\b([A-Z][A-Z0-9_]*)(\*?)\.")


@dataclass(frozen=True, slots=True)
class Finding:
    """Rules that leave a quantity true in other messages the vehicle may send.

    ``left`` pairs each such message's name with how the warning spells the
    carrier (``RANGEFINDER.distance``, with a condition when it carries one
    sensor only). ``uncovered``: a quantity rule, and ``left`` holds what the
    quantity's carrier table does not rewrite.
    """

    head: str  # "rules[0] rewrite rangefinder distance in DISTANCE_SENSOR" / "rules[0] (altitude up)"
    left: tuple[tuple[frozenset[str], str], ...]
    tail: str = ""  # " (target quantity: rangefinder rewrites them all)"
    uncovered: bool = False

    @property
    def messages(self) -> frozenset[str]:
        """Every message whose sight makes this finding real."""
        return frozenset().union(*(names for names, _ in self.left))

    def text(self, seen: Collection[str] | None = None) -> str | None:
        """The warning: conditional when ``seen`` is None (no vehicle known); else about the carriers among
        the messages the vehicle was seen sending, None while it sent none of them."""
        if seen is None:
            spelled = [s for _, s in self.left]
        else:
            spelled = [s for names, s in self.left if names & set(seen)]
            if not spelled:
                return None
        if self.uncovered:
            sep = "; ".join(spelled)
            if seen is None:
                return f"{self.head}: not rewritten, may still carry the truth if the vehicle sends them: {sep}"
            return f"{self.head}: not rewritten, sent by this vehicle and may still carry the truth: {sep}"
        verb = "still carries" if len(spelled) == 1 else "still carry"
        cond = "" if seen is not None else (" if the vehicle sends it" if len(spelled) == 1 else
                                            " if the vehicle sends them")  # fmt: skip
        return f"{self.head}; {', '.join(spelled)} {verb} the true value{cond}{self.tail}"


def message_names(spelled: str) -> frozenset[str]:
    """The message names in a carrier's spelling: ``SCALED_PRESSURE*.press_abs, HIGHRES_IMU.abs_pressure`` ->
    SCALED_PRESSURE, SCALED_PRESSURE2, SCALED_PRESSURE3, HIGHRES_IMU."""
    out: set[str] = set()
    for name, star in _MESSAGE_NAME.findall(spelled):
        out |= {name, f"{name}2", f"{name}3"} if star else {name}
    return frozenset(out)


def _toward_ground(profile: Profile) -> list[tuple[int, RuleBase]]:
    return [(i, r) for i, r in enumerate(profile.rules) if DOWNLINK in rule_directions(r)]


def _fields_hit(rule: RuleBase) -> set[tuple[str, str]]:
    """(message, field) pairs the rule rewrites or drops."""
    t = rule.target
    if t.quantity is not None:
        comp = None if rule.frame_level else t.field or DEFAULT_COMPONENT[t.quantity]
        return {(c.message, c.field) for c in carriers_of(t.quantity, comp)}
    if rule.frame_level or getattr(rule, "scope", None) == "frame":
        return {(t.message, f) for f in MESSAGES[t.message].fields}
    return {(t.message, t.field or MESSAGES[t.message].default_field or "")}


def findings(profile: Profile) -> list[Finding]:
    """One finding per quantity rule with uncovered carriers, and per (quantity, component) that message rules
    rewrite in some carriers and leave true in others; rules toward the vehicle only are left out."""
    rules = _toward_ground(profile)
    by_field = {(c.message, c.field): c for c in CARRIERS}
    hit: set[tuple[str, str]] = set()
    for _, rule in rules:
        hit |= _fields_hit(rule)
    out: list[Finding] = []
    groups: dict[tuple[str, str], tuple[list[int], list[str]]] = {}  # (quantity, component) -> rules, messages
    ids: set[int] | None = set()  # the rangefinder ids the message rules pick (None: some rule picks every id)
    for i, rule in rules:
        t = rule.target
        if t.quantity is not None:
            comps = COMPONENTS[t.quantity] if rule.frame_level else (t.field or DEFAULT_COMPONENT[t.quantity],)
            left = tuple((message_names(name), name) for name, _ in NOT_COVERED[t.quantity])
            out.append(Finding(f"rules[{i}] ({t.quantity} {'/'.join(c for c in comps if c)})", left, uncovered=True))
            continue
        spec = MESSAGES[t.message]
        names = list(spec.fields) if rule.frame_level or getattr(rule, "scope", None) == "frame" else [
            t.field or spec.default_field or ""]  # fmt: skip
        for name in names:
            mine = by_field.get((t.message, name))
            if mine is None:
                continue
            if mine.sensor == "id" and ids is not None:
                picked = t.sensor_ids()
                ids = None if picked is None else ids | set(picked)
            group_rules, messages = groups.setdefault((mine.quantity, mine.component), ([], []))
            if i not in group_rules:
                group_rules.append(i)
            if t.message not in messages:
                messages.append(t.message)
    for (q, comp), (group_rules, messages) in groups.items():
        left = tuple((frozenset((c.message,)), spelled) for c in carriers_of(q, comp)
                     if (c.message, c.field) not in hit and (spelled := _spell(c, ids)) is not None)  # fmt: skip
        if left:
            target = f"quantity: {q}" + (f", field: {comp}" if DEFAULT_COMPONENT[q] is None else "")
            head = f"rules[{', '.join(map(str, group_rules))}] rewrite {q} {comp} in {', '.join(messages)}"
            out.append(Finding(head, left, f" (target {target} rewrites them all)"))
    return out


def _spell(carrier: Carrier, ids: set[int] | None) -> str | None:
    """A carrier left true (None: it cannot carry what the rules attack); one that carries only the primary
    downward rangefinder says when, if the rules pick no id 0."""
    name = f"{carrier.message}.{carrier.field}"
    if carrier.sensor != "primary" or ids is None or 0 in ids:
        return name
    if ids and min(ids) >= ANCHOR_BASE:
        return None  # anchor and peer links are never the vehicle's downward rangefinder
    picked = ", ".join(map(str, sorted(ids)))
    return f"{name} (if sensor {picked} is the vehicle's lowest-id downward rangefinder)"


def true_copies(profile: Profile) -> list[str]:
    """The findings worded for an unknown vehicle (``secuav-attack validate``)."""
    return [text for f in findings(profile) if (text := f.text()) is not None]


_REPORTS = {
    "rangefinder": "ArduPilot in its own DISTANCE_SENSOR and RANGEFINDER, PX4 in its DISTANCE_SENSOR",
    "altitude": "in its own height messages (GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ...)",
    "position": "in its own position messages (GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ...)",
}


def vehicle_reports(profile: Profile) -> list[str]:
    """One note per rule toward the vehicle: the autopilot acts on the lie and reports it itself."""
    by_field = {(c.message, c.field): c for c in CARRIERS}
    out: list[str] = []
    for i, rule in enumerate(profile.rules):
        if UPLINK not in rule_directions(rule):
            continue
        t = rule.target
        if t.quantity is not None:
            comp = t.field or DEFAULT_COMPONENT[t.quantity] or "/".join(COMPONENTS[t.quantity])
            quantity, where = t.quantity, f"every carrier of {t.quantity}"
        else:
            spec = MESSAGES[t.message]
            name = t.field or spec.default_field or ""
            carrier = by_field.get((t.message, name))
            if carrier is None:
                what = t.message if rule.frame_level or not name else f"{t.message}.{name}"
                out.append(f"rules[{i}] change {what} toward the vehicle: the autopilot acts on what it receives")
                continue
            quantity, comp, where = carrier.quantity, carrier.component, t.message
        out.append(f"rules[{i}] feed the vehicle a false {quantity} {comp} ({where}, toward the vehicle): an "
                   f"autopilot that uses it reports the lie itself ({_REPORTS[quantity]}), so no true copy is "
                   "left on the wire")  # fmt: skip
    return out

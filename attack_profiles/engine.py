"""The engine: applies one profile to live MAVLink messages or to an offline array.

Live (the proxy's attack stage)::

    engine = Engine(profile, seed=0, scenario=scenario)
    if msgid in engine.message_ids:          # decode only these
        action = engine.process(now_s, msgid, fields, Direction.DOWNLINK, sysid, compid)

``fields`` is pymavlink's decoded field dict in wire units; ``Action.fields``
holds the changed fields, also in wire units, clamped to what the wire type can
carry (the names of clamped fields are in ``Action.clamped``).

Offline (the evaluation)::

    z_attacked = engine.apply_array(t_s, z_m, sensor_ids, position_ned_m=attacker_view)

in physical units, NaN for a missing or dropped sample.

Rules apply in profile order, each to the value the previous rules left. A rule
that drops the frame ends the chain. Stateful primitives keep their state per
target (vehicle, sensor id), and every call of :meth:`Engine.apply_array` starts
from fresh state, so it is repeatable; the live state starts at
`Engine.activate`.

No reading: A sensor says "I have no reading" in the value itself, and an offset
must not turn that into a believable one (ArduPilot on the ground sends
DISTANCE_SENSOR ``current_distance`` 0 under ``min_distance`` 20 cm; +5 m made it
5 m). With a rule's ``out_of_range: keep`` (the default) these pass the rule by,
unchanged:

- DISTANCE_SENSOR ``current_distance`` outside ``[min_distance, max_distance]``,
  or ``signal_quality`` 1 (invalid);
- RANGEFINDER ``distance`` outside the limits of the DISTANCE_SENSOR it mirrors
  (ArduPilot's primary downward one), or while that one is flagged invalid; 0 m
  before any DISTANCE_SENSOR was seen;
- lat/lon (and the AMSL height beside them) of GLOBAL_POSITION_INT,
  TERRAIN_REPORT, AHRS2, AHRS3, SIMSTATE while they read 0/0 (no position yet),
  and of GPS_RAW_INT / GPS2_RAW below a 2-D fix; their ``alt_ellipsoid`` when 0;
- ALTITUDE ``altitude_terrain`` below -1000 m and ``bottom_clearance`` below 0
  (both "unknown"); HIGHRES_IMU ``pressure_alt`` when ``fields_updated`` lacks its bit.

An attacked range that was a reading stays one: it is clamped to the sensor's
own ``[min_distance, max_distance]`` and the field is named in ``Action.clamped``
(the proxy notes it on the frame), so a bias never pushes a reading into the
"no target" band either. ``set`` writes the profile's value as given (a profile
that forges "reads 0" says so), and ``garbage`` ignores both (a sensor gone
mad). ``out_of_range: attack`` attacks every value and bounds it by the wire type
only, as before. Frame rules (drop, delay, intermittent) act on every frame.
Offline arrays (``Engine.apply_array``) carry no limits: NaN is their "no reading".

Repeating a verdict: for the ids in ``Engine.memo_fields`` (``msgid -> the field left out``, the
message's time field, or ``None``), the verdict on a frame is a function of its payload less that field,
of its sysid and direction, and of the time. ``Engine.steady_until(now_s, msgid, fields, direction, sysid)``
says until when it stays the one `Engine.process` just gave: the next edge of a window on the frame's
chain (``inf`` when none comes), until the next `Engine.activate` (``Engine.epoch`` counts them). The
proxy's fast route repeats such a rewrite in C without asking the engine again (mitm_proxy/README.md,
"The fast path"). Only rules of a ``pure`` primitive (bias, set, scale) qualify; a message whose frames
teach the engine something (the position, the primary rangefinder, the vehicle clock) never does.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from attack_profiles import validity
from attack_profiles.action import FORWARD, Action
from attack_profiles.frame_ops import FrameOps, is_frame_rule, value_warnings
from attack_profiles.primitives import PRIMITIVES, Context, Primitive, Sample, primitive
from attack_profiles.primitives.base import Vec3
from attack_profiles.profile import Profile
from attack_profiles.quantities import DEFAULT_COMPONENT, Carrier, carriers_of
from attack_profiles.rule import IdRange, RuleBase
from attack_profiles.true_copy import true_copies
from attack_profiles.units import (
    EPOCH_USEC_THRESHOLD,
    LOCAL_POSITION_NED_ID,
    MESSAGES,
    FieldSpec,
    MessageSpec,
    lookup,
)
from attack_profiles.where import Match, matches, resolve_where
from mavframe.packet import Direction
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario, Vehicle
from secuav_common.sensor_ids import ANCHOR_BASE, PEER_BASE

_DIRECTIONS = {
    "downlink": frozenset((Direction.DOWNLINK,)),
    "uplink": frozenset((Direction.UPLINK,)),
    "both": frozenset((Direction.DOWNLINK, Direction.UPLINK)),
}


@dataclass(frozen=True, slots=True)
class Window:
    """A rule's time window on the profile clock; :meth:`tau` is the time into it or ``None``."""

    start_s: float
    length_s: float  # inf: no end
    period_s: float | None

    @classmethod
    def of(cls, rule: RuleBase) -> Window:
        length = math.inf if rule.end_s is None else rule.end_s - rule.start_s
        return cls(rule.start_s, length, rule.repeat_period_s)

    def tau(self, t_s: float) -> float | None:
        d = t_s - self.start_s
        if d < 0.0:
            return None
        if self.period_s is not None:
            d %= self.period_s
        return d if d < self.length_s else None

    @property
    def always_on(self) -> bool:
        """In force from the clock's zero on, for good: :meth:`tau` is never ``None`` at ``t_s >= 0``."""
        return self.start_s == 0.0 and (self.length_s == math.inf or (self.period_s is not None
                                                                      and self.length_s >= self.period_s))  # fmt: skip

    def next_edge(self, t_s: float) -> float:
        """The first time after ``t_s`` at which whether :meth:`tau` is ``None`` may change (``inf``: never).

        The window is half-open (``[start, start + length)``, recurring), so ``tau(x) is None`` is the same
        for every ``x`` in ``[t_s, next_edge(t_s))``."""
        if t_s < self.start_s:
            return self.start_s
        length, period = self.length_s, self.period_s
        if period is None:
            end = self.start_s + length  # inf + start is inf
            return end if t_s < end else math.inf
        if length >= period:  # one occurrence runs into the next: on for good
            return math.inf
        into = (t_s - self.start_s) % period  # as tau reads it
        edge = t_s + (length - into if into < length else period - into)
        return edge if edge > t_s else math.nextafter(t_s, math.inf)


@dataclass(slots=True)
class _Compiled:
    """One rule, resolved for fast matching."""

    index: int
    prim: Primitive
    window: Window
    stateful: bool
    directions: frozenset[Direction]
    sysid: int | None
    ids: frozenset[int] | None
    field: str | None  # None: frame-level primitive
    spec: FieldSpec | None
    needs_position: bool
    keep: bool = True  # out_of_range: keep: a frame's no-reading passes this rule by
    clamp: bool = True  # ... and what it writes stays inside the sensor's [min, max]
    factor: float = 1.0  # quantity targets: quantity value = field value (physical) * factor
    lat_field: str | None = None  # ... times cos(this latitude), for a longitude
    lat_scale: float = 0.0  # degrees per wire unit of lat_field
    where: Match | None = None  # the target's where: frames that do not match are not this rule's


@dataclass(slots=True)
class _State:
    """Everything that changes while a profile runs; rebuilt by activate() and per apply_array()."""

    plans: dict[int, tuple[_Compiled, ...]]
    active_at_s: float | None = None
    vehicle_time_s: dict[int, float] = field(default_factory=dict)  # sysid -> last time_boot seen
    positions: dict[int, Vec3] = field(default_factory=dict)  # sysid -> last LOCAL_POSITION_NED
    # sysid -> DISTANCE_SENSOR id -> (min m, max m, invalid, downward), for RANGEFINDER (ArduPilot's primary)
    rangefinders: validity.Rangefinders = field(default_factory=dict)
    chains: dict[tuple[int, int, int, Direction], tuple[_Compiled, ...]] = field(default_factory=dict)
    windows: dict[tuple[int, int, int, Direction], tuple[Window, ...]] = field(default_factory=dict)  # of chains
    sample: Sample = field(default_factory=Sample)


_MAX_CACHED_CHAINS = 4096
_EDGE_MARGIN_S = 1e-6  # steady_until ends this much before a window's edge


def _repeatable(r: _Compiled) -> bool:
    """A value rule whose verdict on a frame depends on the frame (and its window) only."""
    return r.prim.pure and not r.stateful and not r.needs_position and r.field is not None


def _sensor_id(st: _State, msgid: int, msg: MessageSpec, fields: Mapping[str, Any], sysid: int) -> int:
    """The sensor id a frame's chain is chosen by: its id field; RANGEFINDER's, the primary rangefinder's."""
    if msgid == validity.RANGEFINDER_ID:
        return validity.primary(st.rangefinders, sysid)
    return fields.get(msg.id_field, -1) if msg.id_field is not None else -1


def _run_chain(rules: Sequence[_Compiled], s: Sample, working: dict[str, float]) -> tuple[int, ...]:
    """The one rule chain, for live frames and offline arrays alike.

    Each rule in its window rewrites ``s`` (its field's value comes from
    ``working``, what earlier rules left, else from the message); stateful
    rules also see samples outside their window. A drop ends the chain.
    ``working`` ends with every rewritten field; returns the indices of the
    rules that acted.
    """
    acted: list[int] = []
    t = s.t_s
    k = 1.0
    for r in rules:
        if r.where is not None and not matches(r.where, s.fields):
            continue
        tau = r.window.tau(t)
        if tau is None and not r.stateful:
            continue
        name = r.field
        if name is not None:
            if r.keep and name in s.unread:  # no reading: it stays one
                continue
            value = working.get(name)
            if value is None:
                raw = s.fields.get(name)
                if raw is None:
                    continue
                value = raw * r.spec.scale  # type: ignore[union-attr]
            k = r.factor
            if r.lat_field is not None:
                lat = s.fields.get(r.lat_field)
                if lat is None:
                    continue
                k *= math.cos(math.radians(lat * r.lat_scale))
                if abs(k) < 1e-9:  # at a pole a longitude carries no east
                    continue
            s.value = value * k if k != 1.0 else value
        r.prim.apply(s, tau)
        if tau is None:
            continue
        if not acted or acted[-1] != r.index:  # frame-scope garbage is one rule over many fields
            acted.append(r.index)
        if s.drop:
            break
        if name is not None:
            working[name] = s.value / k if k != 1.0 else s.value
            if not r.clamp:
                s.free.add(name)
    return tuple(acted)


def _rule_seed(profile_seed: int, engine_seed: int, index: int | str) -> int:
    # A hash rather than arithmetic so neighbouring seeds give unrelated streams.
    digest = hashlib.sha256(f"{profile_seed}:{engine_seed}:{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


class Engine:
    """Applies ``profile``; ``scenario`` is needed for the coordinated spoof and to check sensor ids."""

    def __init__(self, profile: Profile, seed: int = 0, scenario: Scenario | None = None) -> None:
        self.profile = profile
        self.seed = seed
        self.scenario = scenario
        self._anchors: dict[int, Vec3] = {}
        self._noise: dict[int, float] = {}
        if scenario is not None:
            self.validate_against(scenario)
            self._anchors = {ANCHOR_BASE + k: pos for k, pos in scenario.anchor_positions().items()}
            self._noise = _noise_by_id(scenario)
        for i, rule in enumerate(profile.rules):
            if rule.needs_anchors and scenario is None:
                raise InputError(profile.source, f"rules[{i}].kind", rule.kind, "needs a scenario for anchor positions")
        self._msg_by_id: dict[int, MessageSpec] = {
            MESSAGES[name].msgid: MESSAGES[name]
            for r in profile.rules
            if not is_frame_rule(r)
            for name in _messages_of(r)
        }
        # Frame operations (inject, duplicate, frame_replay, mission_shift): live links only, run by the proxy.
        self.frame_ops: FrameOps | None = FrameOps.of(profile, seed)
        # Fields outside a typed message's table, and array elements, that rules rewrite or match on.
        self._elements: dict[int, tuple[tuple[str, str, int], ...]] = {}
        self._extend_specs()
        self._tracks_position = any(r.needs_position for r in profile.rules)
        # RANGEFINDER follows ArduPilot's primary downward rangefinder: learnt from DISTANCE_SENSOR.
        self._tracks_rangefinders = validity.RANGEFINDER_ID in self._msg_by_id
        ids = set(self._msg_by_id)
        if self._tracks_position:
            ids.add(LOCAL_POSITION_NED_ID)
        if self._tracks_rangefinders:
            ids.add(validity.DISTANCE_SENSOR_ID)
        self.warnings: tuple[str, ...] = tuple(value_warnings(profile, true_copies))
        if self.frame_ops is not None:
            ids |= self.frame_ops.message_ids
        self.message_ids: frozenset[int] = frozenset(ids)
        self._live = self._new_state()
        # Under ``clock: vehicle`` a message without a boot time of its own takes the last one any frame brought.
        self._clock_read = self.profile.clock == "vehicle" and any(
            m.time_field != "time_boot_ms" for m in self._msg_by_id.values())  # fmt: skip
        self.field_filters: dict[int, tuple[str, frozenset[int]]] = self._field_filters()
        self.memo_fields: dict[int, str | None] = self._memo_fields()
        self.epoch = 0  # counts activate(): what was learnt of an earlier activation's verdicts no longer holds

    def _field_filters(self) -> dict[int, tuple[str, frozenset[int]]]:
        """For the ids in :attr:`message_ids` whose untargeted frames :meth:`process` forwards without a trace:
        ``msgid -> (id field, the ids targeted)``. A frame of such a message whose id field holds none of them
        may skip the engine altogether (the proxy's fast route keeps it in C: mitm_proxy/README.md), and the
        engine behaves exactly as if it had seen it.

        That holds when every rule on the message names its sensor ids, and nothing the engine keeps is
        learnt from other sensors' frames: not the primary rangefinder (a RANGEFINDER rule reads every
        DISTANCE_SENSOR), not the position (LOCAL_POSITION_NED has no id), not a frame operation's (they
        take whole messages), and not the vehicle's clock unless nothing reads it back (under ``clock:
        vehicle`` a message without a boot time of its own takes the last one any frame brought)."""
        ops = frozenset() if self.frame_ops is None else self.frame_ops.message_ids
        if self._clock_read:
            return {}
        out: dict[int, tuple[str, frozenset[int]]] = {}
        for msgid, rules in self._live.plans.items():
            msg = self._msg_by_id.get(msgid)
            if msg is None or msg.id_field is None or not rules or msgid in ops:
                continue
            if self._tracks_rangefinders and msgid == validity.DISTANCE_SENSOR_ID:
                continue
            if self._tracks_position and msgid == LOCAL_POSITION_NED_ID:
                continue
            if any(r.ids is None for r in rules):
                continue
            out[msgid] = (msg.id_field, frozenset().union(*(r.ids for r in rules)))  # type: ignore[arg-type]
        return out

    def _memo_fields(self) -> dict[int, str | None]:
        """The ids whose verdict :meth:`steady_until` vouches for: ``msgid -> the field left out of the key``
        (the message's time field when nothing reads it) or ``None`` (the whole payload is the key).

        A message qualifies when the verdict on its frames is a function of the payload (less that field)
        and of the time alone: every rule on it is :attr:`~attack_profiles.primitives.base.Primitive.pure`
        (no frame rule: drop, delay... are not repeated), and nothing the engine learns comes from its frames
        (the position, the primary rangefinder, the vehicle clock another message reads, a frame operation).
        Under ``clock: vehicle`` its own boot time is the clock, so every rule on it must be always on."""
        if self._clock_read:
            return {}
        ops = frozenset() if self.frame_ops is None else self.frame_ops.message_ids
        vehicle = self.profile.clock == "vehicle"
        out: dict[int, str | None] = {}
        for msgid, msg in self._msg_by_id.items():
            if msgid in ops:
                continue
            rules = self._live.plans.get(msgid, ())
            if self._tracks_position and msgid == LOCAL_POSITION_NED_ID:
                continue
            if self._tracks_rangefinders and msgid in validity.RANGED:
                continue
            if not all(_repeatable(r) for r in rules):
                continue
            if vehicle and (msg.time_field != "time_boot_ms" or not all(r.window.always_on for r in rules)):
                continue
            time_field = msg.time_field
            if time_field is not None and any(
                    r.field == time_field or (r.where is not None and any(n == time_field for n, _ in r.where))
                    for r in rules):  # fmt: skip
                time_field = None
            out[msgid] = time_field
        return out

    def _extend_specs(self) -> None:
        """Add to each targeted message the fields outside its typed table that rules rewrite, and note the
        array elements rules rewrite or match on (a profile of typed fields changes nothing here)."""
        extra: dict[int, dict[str, FieldSpec]] = {}
        elements: dict[int, dict[str, tuple[str, str, int]]] = {}
        for rule in self.profile.rules:
            if rule.target.message is None or is_frame_rule(rule):
                continue
            msg = MESSAGES[rule.target.message]
            names = [n for n in rule.fields_of(msg) if n is not None] + list(rule.target.where or ())
            for name in names:
                spec = msg.field(name)
                if spec is None:  # a text field in where
                    continue
                if name not in msg.fields:
                    extra.setdefault(msg.msgid, {})[name] = spec
                if spec.array is not None:
                    elements.setdefault(msg.msgid, {})[name] = (name, spec.array, spec.index)
        for msgid, fields in extra.items():
            msg = self._msg_by_id[msgid]
            self._msg_by_id[msgid] = dataclasses.replace(msg, fields={**msg.fields, **fields})
        self._elements = {msgid: tuple(found.values()) for msgid, found in elements.items()}

    # -- checks ---------------------------------------------------------------------------------------

    def validate_against(self, scenario: Scenario) -> None:
        """Raise ``InputError`` naming the rule and id if a target names a vehicle or sensor the scenario lacks."""
        source = self.profile.source
        sysids = {v.sysid for v in scenario.vehicles}
        anchors = {ANCHOR_BASE + a.id for a in scenario.world.anchors}
        for i, rule in enumerate(self.profile.rules):
            target = rule.target
            if target.sysid is not None and target.sysid not in sysids:
                raise InputError(
                    source, f"rules[{i}].target.sysid", target.sysid, f"scenario {scenario.name!r} has no such vehicle"
                )
            wanted = target.sensor_ids()
            if wanted is None or (target.message is not None and MESSAGES[target.message].id_field is None):
                continue
            vehicles = [v for v in scenario.vehicles if target.sysid in (None, v.sysid)]
            present = set().union(*(_sensor_ids(v, anchors) for v in vehicles))
            if rule.needs_anchors:
                present &= anchors
            if isinstance(target.sensor_id, IdRange):
                # A range is a shorthand ("the anchor links 10-49"): it must reach some sensor, not all.
                if not wanted & present:
                    raise InputError(
                        source,
                        f"rules[{i}].target.sensor_id",
                        target.sensor_id.model_dump(),
                        f"scenario {scenario.name!r} has no sensor in this range (ids: {sorted(present)})",
                    )
                continue
            for sid in sorted(wanted):
                if sid not in present:
                    raise InputError(
                        source,
                        f"rules[{i}].target.sensor_id",
                        sid,
                        f"scenario {scenario.name!r} has no such sensor (ids: {sorted(present)})",
                    )

    # -- live path ------------------------------------------------------------------------------------

    def activate(self, now_s: float, *, rebuild: bool = True) -> None:
        """Start (or restart) the profile: fresh state, activation clock zero at ``now_s``.

        ``rebuild=False`` keeps the state the constructor built, for an engine that has processed nothing
        yet: building it costs ~0.1 ms a rule, which a proxy pays off its forwarding loop.
        """
        if rebuild:
            self._live = self._new_state()
        self._live.active_at_s = now_s
        self.epoch += 1
        if self.frame_ops is not None:
            self.frame_ops.activate(now_s)

    def process(
        self,
        now_s: float,
        msgid: int,
        fields: Mapping[str, Any],
        direction: Direction,
        sysid: int,
        compid: int,
    ) -> Action:
        """Decide what happens to one decoded message (fields in wire units).

        ``now_s`` is the caller's monotonic clock; the first call activates the
        profile if :meth:`activate` was not called.
        """
        st = self._live
        if msgid not in st.plans:
            return FORWARD
        if self._tracks_position and msgid == LOCAL_POSITION_NED_ID:
            x, y, z = fields.get("x"), fields.get("y"), fields.get("z")
            if x is not None and y is not None and z is not None:
                st.positions[sysid] = (x, y, z)
        if self._tracks_rangefinders and msgid == validity.DISTANCE_SENSOR_ID and direction is Direction.DOWNLINK:
            validity.track_rangefinder(st.rangefinders, sysid, fields)
        msg = self._msg_by_id.get(msgid)
        if msg is None:  # watched only for the position
            return FORWARD
        original = fields
        if self._elements:
            elements = self._elements.get(msgid)
            if elements is not None:  # array elements become fields of their own ("distances[3]")
                fields = _with_elements(fields, elements)
        t = self._clock(st, now_s, msg, fields, sysid)  # first: it also tracks the vehicle's clock
        if t is None:
            return FORWARD
        sid = _sensor_id(st, msgid, msg, fields, sysid)
        rules = self._chain(st, msgid, sysid, sid, direction)
        if not rules:
            return FORWARD
        s = st.sample
        s.t_s, s.key, s.fields = t, (sysid, sid), fields
        s.drop, s.delay_s, s.offline = False, 0.0, False
        s.position_ned_m = st.positions.get(sysid)
        limits = validity.limits(st.rangefinders, msgid, fields, sysid, sid) if msgid in validity.RANGED else None
        s.unread = validity.unread(msgid, fields, limits) if msgid in validity.MAY_BE_UNREAD else validity.NOTHING
        if s.free:
            s.free.clear()
        working: dict[str, float] = {}
        acted = _run_chain(rules, s, working)
        if not acted:
            return FORWARD
        if s.drop:
            return Action(drop=True, rules=acted)
        changed: dict[str, Any] = {}
        clamped: list[str] = []
        for name, value in working.items():
            if limits is not None and name == limits[0] and name not in s.free:
                lo, hi = limits[1], limits[2]
                if lo <= hi and not lo <= value <= hi:
                    value = min(max(value, lo), hi)  # an attacked reading stays inside the sensor's range
                    clamped.append(name)
            wire, was_clamped = msg.fields[name].to_wire(value)
            if was_clamped and name not in clamped:
                clamped.append(name)
            if wire != fields.get(name):
                changed[name] = wire
        if changed and fields is not original:
            changed = _whole_arrays(changed, msg, original)
        return Action(fields=changed or None, delay_s=s.delay_s, rules=acted, clamped=tuple(clamped))

    def steady_until(
        self, now_s: float, msgid: int, fields: Mapping[str, Any], direction: Direction, sysid: int
    ) -> float | None:
        """Until when (the caller's monotonic clock, as :meth:`process`'s ``now_s``) every frame of ``msgid``
        from ``sysid`` in ``direction`` whose payload, less the field :attr:`memo_fields` leaves out, equals
        that of the frame just processed at ``now_s`` with ``fields`` gets the verdict that frame got
        (``inf``: until the next :meth:`activate`); ``None`` when ``msgid`` is not in :attr:`memo_fields` or
        the profile was never activated.

        Only the rules' windows can change such a verdict, so the answer is the next edge of a window on
        the frame's chain (the same edge for a rule that did not act: it may begin to)."""
        st = self._live
        active_at = st.active_at_s
        if msgid not in self.memo_fields or active_at is None:
            return None
        if self.profile.clock == "vehicle":  # the message's rules are always on
            return math.inf
        msg = self._msg_by_id[msgid]
        key = (msgid, sysid, _sensor_id(st, msgid, msg, fields, sysid), direction)
        windows = st.windows.get(key)
        if windows is None:
            windows = tuple(dict.fromkeys(r.window for r in self._chain(st, *key)))  # the distinct ones
            if len(st.windows) < _MAX_CACHED_CHAINS:
                st.windows[key] = windows
        t = now_s - active_at
        edge = math.inf  # an empty chain: steady for good
        for w in windows:
            e = w.next_edge(t)
            if e < edge:
                edge = e
        # Margin: the clock's time into the window is one subtraction away from now_s, rounded either way.
        return active_at + edge - _EDGE_MARGIN_S if edge != math.inf else math.inf

    def _chain(self, st: _State, msgid: int, sysid: int, sid: int, direction: Direction) -> tuple[_Compiled, ...]:
        """The rules that target this (message, vehicle, sensor, direction), in profile order; cached."""
        key = (msgid, sysid, sid, direction)
        rules = st.chains.get(key)
        if rules is None:
            rules = tuple(
                r
                for r in st.plans.get(msgid, ())
                if r.sysid in (None, sysid) and direction in r.directions and (r.ids is None or sid in r.ids)
            )
            if len(st.chains) < _MAX_CACHED_CHAINS:  # ids come off the wire: bound what they can make us keep
                st.chains[key] = rules
        return rules

    def _clock(self, st: _State, now_s: float, msg: MessageSpec, fields: Mapping[str, Any], sysid: int) -> float | None:
        if self.profile.clock == "activation":
            if st.active_at_s is None:
                st.active_at_s = now_s
            return now_s - st.active_at_s
        # Vehicle clock: the message's own boot time, else the last one this vehicle sent.
        if msg.time_field == "time_boot_ms":
            ms = fields.get("time_boot_ms")
            if ms is not None:
                st.vehicle_time_s[sysid] = ms * 1e-3
                return ms * 1e-3
        elif msg.time_field == "time_usec":
            us = fields.get("time_usec")
            if us is not None and 0 < us < EPOCH_USEC_THRESHOLD:  # since boot, not a UNIX time
                st.vehicle_time_s[sysid] = us * 1e-6
                return us * 1e-6
        return st.vehicle_time_s.get(sysid)

    # -- offline path ---------------------------------------------------------------------------------

    def apply_array(
        self,
        t_s: np.ndarray,
        z: np.ndarray,
        sensor_ids: Sequence[int],
        message: str = "DISTANCE_SENSOR",
        field: str = "current_distance",
        *,
        sysid: int = 1,
        position_ned_m: np.ndarray | None = None,
    ) -> np.ndarray:
        """Attack an offline stream: ``z[k, j]`` is sensor ``sensor_ids[j]`` at ``t_s[k]``.

        Physical units in and out (metres for ranges); NaN is a missing sample
        and stays missing; a dropped sample becomes NaN; delay shows the value
        from ``delay_s`` earlier. ``t_s`` is read on the profile's clock
        (seconds since activation, or vehicle boot time) and must not decrease.
        ``position_ned_m`` (T x 3) is the vehicle's position as the attacker
        reads it, needed by rules that use it (the coordinated spoof). Only rules
        targeting ``message``/``field`` (or whole frames of ``message``) on the
        downlink of ``sysid`` apply. Values are clamped to the wire range.
        """
        t_arr = np.asarray(t_s, dtype=float)
        z_arr = np.asarray(z, dtype=float)
        if z_arr.ndim != 2 or t_arr.shape != (z_arr.shape[0],) or len(sensor_ids) != z_arr.shape[1]:
            raise ValueError(f"need t_s[T], z[T, p], p sensor ids; got {t_arr.shape}, {z_arr.shape}, {len(sensor_ids)}")
        if t_arr.size and np.any(np.diff(t_arr) < 0):
            raise ValueError("t_s must not decrease")
        msg = lookup(message)
        found = None if msg is None else msg.field(field)
        if msg is None or found is None:
            raise ValueError(f"{message}.{field} is not an attackable field")
        spec = found
        st = self._new_state()
        st.sample.unread = frozenset()
        columns = [
            tuple(
                r for r in self._chain(st, msg.msgid, sysid, int(sid), Direction.DOWNLINK) if r.field in (None, field)
            )
            for sid in sensor_ids
        ]
        positions: np.ndarray | None = None
        for r in (r for col in columns for r in col):
            if r.needs_position:
                if position_ned_m is None:
                    raise ValueError(f"rules[{r.index}] ({r.prim.kind}) needs position_ned_m")
                positions = np.asarray(position_ned_m, dtype=float)
                if positions.shape != (t_arr.size, 3):
                    raise ValueError(f"position_ned_m must be T x 3, got {positions.shape}")
        lo, hi = sorted((spec.lo * spec.scale, spec.hi * spec.scale))
        out = z_arr.copy()
        s = st.sample
        s.offline = True
        for k in range(t_arr.size):
            s.t_s = float(t_arr[k])
            s.position_ned_m = None if positions is None else tuple(positions[k])  # type: ignore[assignment]
            for j, rules in enumerate(columns):
                value = z_arr[k, j]
                if not rules or value != value:  # untargeted, or no sample: nothing to attack
                    continue
                s.key = (sysid, int(sensor_ids[j]))
                s.fields = {field: float(value) / spec.scale}
                s.value = float(value)
                s.drop, s.delay_s = False, 0.0
                _run_chain(rules, s, {field: s.value})
                v = s.value
                out[k, j] = math.nan if s.drop else (v if v != v else min(max(v, lo), hi))
        return out

    # -- construction ---------------------------------------------------------------------------------

    def _new_state(self) -> _State:
        plans: dict[int, list[_Compiled]] = {mid: [] for mid in self.message_ids}
        for i, rule in enumerate(self.profile.rules):
            if is_frame_rule(rule):
                continue  # the frame operations keep their own state (attack_profiles/frame_ops.py)
            cls = PRIMITIVES.get(rule.kind) or primitive(rule.kind)  # type: ignore[attr-defined]
            if cls is None:  # a plugin's rule that reached a process without the plugin
                raise InputError(self.profile.source, f"rules[{i}].kind", rule.kind, "no such primitive installed here")
            keep = rule.out_of_range == "keep" and rule.within_limits
            clamp = keep and rule.clamps_to_limits
            common = {"index": i, "window": Window.of(rule), "stateful": cls.stateful, "sysid": rule.target.sysid,
                      "directions": _DIRECTIONS[rule.target.direction], "ids": rule.target.sensor_ids(),
                      "needs_position": rule.needs_position, "keep": keep, "clamp": clamp}  # fmt: skip
            if rule.target.message is not None:
                msg = MESSAGES[rule.target.message]
                if rule.target.where is not None:
                    common["where"] = resolve_where(msg, rule.target.where, f"rules[{i}].target.where",
                                                    self.profile.source)  # fmt: skip
                for name in rule.fields_of(msg):
                    spec = msg.field(name) if name is not None else None
                    seed = _rule_seed(self.profile.seed, self.seed, i if name is None else f"{i}.{name}")
                    ctx = Context(i, spec, random.Random(seed), self._anchors, self._noise)
                    plans[msg.msgid].append(_Compiled(prim=cls(rule, ctx), field=name, spec=spec, **common))
                continue
            for message, carrier in _carriers(rule):
                msg = MESSAGES[message]
                spec = None if carrier is None else msg.fields[carrier.field]
                name = None if carrier is None else carrier.field
                seed = _rule_seed(self.profile.seed, self.seed, f"{i}.{message}" + ("" if name is None else f".{name}"))
                ctx = Context(i, spec, random.Random(seed), self._anchors, self._noise)
                conv: dict[str, Any] = {}
                if carrier is not None:
                    conv["factor"] = carrier.factor
                    if carrier.lat_field is not None:
                        conv["lat_field"] = carrier.lat_field
                        conv["lat_scale"] = msg.fields[carrier.lat_field].scale
                plans[msg.msgid].append(_Compiled(prim=cls(rule, ctx), field=name, spec=spec, **common, **conv))
        return _State(plans={mid: tuple(rs) for mid, rs in plans.items()})


def _with_elements(fields: Mapping[str, Any], elements: tuple[tuple[str, str, int], ...]) -> dict[str, Any]:
    """``fields`` plus the array elements rules read, under their own names."""
    view = dict(fields)
    for name, array, index in elements:
        values = fields.get(array)
        if values is not None and index < len(values):
            view[name] = values[index]
    return view


def _whole_arrays(changed: dict[str, Any], msg: MessageSpec, original: Mapping[str, Any]) -> dict[str, Any]:
    """Changed array elements folded back into their arrays (what the codec packs)."""
    out: dict[str, Any] = {}
    for name, wire in changed.items():
        spec = msg.fields[name]
        if spec.array is None:
            out[name] = wire
            continue
        values = out.get(spec.array)
        if values is None:
            values = out[spec.array] = list(original[spec.array])
        values[spec.index] = wire
    return out


def _messages_of(rule: RuleBase) -> list[str]:
    if rule.target.message is not None:
        return [rule.target.message]
    return list(dict.fromkeys(m for m, _ in _carriers(rule)))


def _carriers(rule: RuleBase) -> list[tuple[str, Carrier | None]]:
    """(message, carrier) pairs a quantity rule acts on; frame-level rules: (message, None) once a message."""
    q = rule.target.quantity
    assert q is not None
    if rule.frame_level:
        return [(m, None) for m in dict.fromkeys(c.message for c in carriers_of(q, rule.target.field))]
    return [(c.message, c) for c in carriers_of(q, rule.target.field or DEFAULT_COMPONENT[q])]


def _noise_by_id(scenario: Scenario) -> dict[int, float]:
    """DISTANCE_SENSOR id -> the noise std the scenario gives that sensor (the largest over vehicles)."""
    out: dict[int, float] = {}
    anchors = {ANCHOR_BASE + a.id for a in scenario.world.anchors}
    for v in scenario.vehicles:
        for r in v.all_rangefinders:
            out[r.id] = max(out.get(r.id, 0.0), r.noise_std_m)
        uwb, iv = v.uwb_ranging, v.sensors.inter_vehicle
        for sid in (_sensor_ids(v, anchors) & set(range(ANCHOR_BASE, PEER_BASE))) if uwb is not None else ():
            out[sid] = max(out.get(sid, 0.0), uwb.noise_std_m)
        for n in iv.peers if iv is not None else ():
            out[PEER_BASE + n] = max(out.get(PEER_BASE + n, 0.0), iv.noise_std_m)
    return out


def _sensor_ids(vehicle: Vehicle, anchors: set[int]) -> set[int]:
    """DISTANCE_SENSOR ids a scenario vehicle's link carries (a companion's fed sensors included)."""
    ids = {r.id for r in vehicle.all_rangefinders}
    uwb = vehicle.uwb_ranging
    if uwb is not None:
        ids |= anchors if uwb.anchors == "all" else {ANCHOR_BASE + k for k in uwb.anchors}
    iv = vehicle.sensors.inter_vehicle
    if iv is not None:
        ids |= {PEER_BASE + n for n in iv.peers}
    return ids

"""The per-link holder of the active attack profile, which the attack stage reads.

Every way of changing the profile (``--profile`` at start, the file reload, MQTT
``secuav/v<sysid>/attack/set``, ``secuav-attack apply``, ``secuav-record``'s
shared engine) goes through the ``attack`` switch (:class:`mitm_proxy.control.attack.AttackSwitch`,
which keeps the verdict and calls :meth:`AttackSlot.prepare` and :meth:`AttackSlot.apply`);
the attack stage reads :attr:`AttackSlot.engine` once per targeted frame. A new
engine is built and checked completely before the single attribute assignment
that installs it, and the event loop runs one callback at a time, so a swap
always falls between two frames. A rejected profile leaves the previous engine
in place, and the switch says why in its state.

When the vehicle signs its frames and the proxy has no key, the pipeline leaves
the frames the profile targets alone (docs/interfaces.md); the slot then says so
in its state's ``warnings`` (``attack.signed_no_key``, one per sending system)
until another profile is installed.

The state names the directions the profile changes (``directions``: ``downlink``,
toward the ground; ``uplink``, toward the vehicle), and the ``attack.applied`` log
line says them in words. A slot made with ``forbid_uplink`` (``secuav-proxy
--no-uplink-attacks``) refuses every profile with a rule toward the vehicle, one
line naming the rule, whichever door it came through; the previous profile stays.

What the profile leaves true on the wire (:mod:`attack_profiles.true_copy`) is
warned about once the vehicle is seen sending such a carrier
(:class:`~mitm_proxy.stages.true_copy_watch.TrueCopyWatch`: ``attack.true_copy``
in the log and the state); a rule toward the vehicle is noted once at install
(``attack.vehicle_reports``): the autopilot will report the lie it was fed.

A profile that would write frames (rewrite a field, inject,
duplicate, replay, shift a mission) in a direction where signed frames already arrived and the proxy
has no key is refused at apply, with the reason, and the previous profile stays: ``unkeyed`` (the
link's :meth:`~mitm_proxy.core.pipeline.Pipeline.unkeyed_signed`, set by the proxy) says where.
Whoever must know when the profile changes (the attack stage, for its clock) is in ``listeners``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

from attack_profiles.control import profile_from_payload
from attack_profiles.directions import check_no_uplink, describe, directions_of
from attack_profiles.engine import Engine
from attack_profiles.frame_ops import needs_key
from attack_profiles.profile import Profile
from attack_profiles.true_copy import findings, vehicle_reports
from mavframe import codec
from mavframe.packet import Direction
from mitm_proxy.stages.true_copy_watch import TrueCopyWatch
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario

__all__ = ["AttackSlot"]

log = logging.getLogger(__name__)
_V = TypeVar("_V")


class _Built(NamedTuple):
    """An engine :meth:`AttackSlot.prepare` built for a request, installed (and started) by ``apply``."""

    engine: Engine
    hash: str  # the profile's content hash (11 ms for 420 rules): computed once, off the loop


class AttackSlot:
    """Active profile of one link (one vehicle)."""

    def __init__(self, sysid: int, scenario: Scenario | None = None, seed: int = 0, *,
                 forbid_uplink: bool = False) -> None:  # fmt: skip
        self.sysid = sysid
        self.scenario = scenario
        self.seed = seed
        self.forbid_uplink = forbid_uplink
        self.engine: Engine | None = None
        self._sent: set[str] = set()  # message names the vehicle was seen sending (the true-copy carriers)
        self._watch: TrueCopyWatch | None = None
        self._ids: frozenset[int] = frozenset()  # the engine's message ids and the watched carriers'
        self._filters: dict[int, tuple[str, frozenset[int]]] = {}  # the engine's, less the watched carriers
        self._memo: dict[int, str | None] = {}  # the engine's memo_fields, less the watched carriers
        self._directions: tuple[str, ...] = ()  # of the engine's profile, kept with it as the hash is
        self.on_install: list[Callable[[AttackSlot], None]] = []  # told after each install or clear (the recorder)
        # False while the proxy is built (its log says warnings only then): it calls say_notes() once it runs
        self.announce = True
        self._hash: str | None = None  # of the engine's profile, kept with it (states are built 5 times a second)
        self._since: float | None = None
        self._signed: dict[int, int] = {}  # sysid -> the first message id left alone for want of a key
        self.unkeyed: Callable[[], frozenset[Direction]] | None = None  # signed directions without a key
        self.listeners: list[Callable[[], None]] = []  # told after every install or clear

    @property
    def message_ids(self) -> frozenset[int]:
        """What the attack stage wants: the profile's messages, and the true-copy carriers not yet seen."""
        return self._ids

    @property
    def field_filters(self) -> dict[int, tuple[str, frozenset[int]]]:
        """Of :attr:`message_ids`, those the stage wants only when a frame's id field holds one of a few values:
        ``msgid -> (field, values)`` (:attr:`attack_profiles.engine.Engine.field_filters`); a carrier still
        watched is wanted whole."""
        return self._filters

    @property
    def memo_fields(self) -> dict[int, str | None]:
        """Of :attr:`message_ids`, those whose verdict the fast route may repeat (``msgid -> the field left out
        of the key``, :attr:`attack_profiles.engine.Engine.memo_fields`); a carrier still watched must reach the
        stage. The same dict while nothing changes."""
        return self._memo

    @property
    def watching(self) -> frozenset[int]:
        """Carrier message ids still to be seen from the vehicle (see :class:`TrueCopyWatch`)."""
        return frozenset() if self._watch is None else self._watch.message_ids

    @property
    def hash(self) -> str | None:
        """The active profile's content hash (None when there is none)."""
        return self._hash

    @property
    def directions(self) -> list[str]:
        """``downlink`` (toward the ground), ``uplink`` (toward the vehicle): what the active profile changes."""
        return list(self._directions)

    def current(self) -> dict[str, Any]:
        """What is in force, as ``attack/state``'s fields (without the verdict)."""
        profile = None if self.engine is None else self.engine.profile
        return {"sysid": self.sysid, "profile": None if profile is None else profile.name,
                "hash": self._hash, "since": self._since, "directions": self.directions,
                "warnings": self.warnings}  # fmt: skip

    def log_fields(self) -> dict[str, Any]:
        """``attack.applied``/``rejected`` say what is in force and which way it changes frames."""
        if self.engine is None:
            return {"sysid": self.sysid, "profile": "none"}
        return {"sysid": self.sysid, "profile": self.engine.profile.name, "directions": ",".join(self.directions),
                "changes": describe(self.directions)}  # fmt: skip

    @property
    def warnings(self) -> list[str]:
        """What keeps the active profile from acting, as ``"code: text"`` (empty while nothing does)."""
        signed = [signed_no_key(sysid, msgid) for sysid, msgid in sorted(self._signed.items())]
        return signed + [f"attack.true_copy: {w}" for w in (() if self._watch is None else self._watch.warnings)]

    def saw(self, msgid: int) -> None:
        """The vehicle sent a frame of ``msgid`` toward the ground that the watch waited for."""
        watch, engine = self._watch, self.engine
        if watch is None or engine is None:
            return
        for warning in watch.see(msgid):
            log.warning("attack.true_copy", extra={"sysid": self.sysid, "profile": engine.profile.name,
                                                   "warning": warning})  # fmt: skip
        self._want(engine, watch)

    def _want(self, engine: Engine, watch: TrueCopyWatch) -> None:
        """What the stage wants while ``watch`` waits: the engine's ids and the carriers', the engine's field
        filters and memo fields less the carriers (a carrier still watched is wanted whole, every frame)."""
        self._ids = engine.message_ids | watch.message_ids
        self._filters = _less_watched(engine.field_filters, watch)
        self._memo = _less_watched(engine.memo_fields, watch)

    def signed_untouched(self, sysid: int, msgid: int) -> None:
        """A signed frame of ``sysid`` the profile targets passed unchanged: the proxy has no signing key."""
        if sysid not in self._signed and self.engine is not None and len(self._signed) < 256:
            self._signed[sysid] = msgid

    def prepare(self, payload: Any, source: str) -> Any:
        """A request's JSON (or a parsed profile, ``None``, an engine) validated into a profile and its engine
        built, not started (pure: the MQTT session runs it off the forwarding loop; a 420-rule profile took
        80 ms)."""
        if isinstance(payload, Engine) or payload is None:
            return payload
        profile = payload if isinstance(payload, Profile) else profile_from_payload(payload, source)
        self._allowed(profile, source)  # refused off the loop, before the engine is built
        return None if profile is None else _Built(Engine(profile, self.seed, self.scenario), profile.content_hash())

    def apply(self, payload: Any, source: str) -> None:
        """A profile, its JSON (a profile, ``{"library": ...}``), ``None`` to clear, a built :class:`Engine`,
        or what :meth:`prepare` made of a request; ``InputError`` refuses it and the previous one stays."""
        if isinstance(payload, _Built):
            engine: Engine | None = payload.engine
            self._allowed(payload.engine.profile, source)
            self._check_signing(payload.engine, source)
            payload.engine.activate(time.monotonic(), rebuild=False)  # built off the loop: only the clock starts
            self.engine, self._hash, self._since = engine, payload.hash, time.time()
            self._signed = {}
            self._warn(engine)
            self._tell()
            return
        if isinstance(payload, Engine):
            engine = payload  # built and started by the caller (secuav-record shares one clock)
            self._allowed(engine.profile, source)
        else:
            profile = payload if isinstance(payload, Profile) or payload is None else profile_from_payload(
                payload, source)  # fmt: skip
            self._allowed(profile, source)
            engine = None if profile is None else Engine(profile, self.seed, self.scenario)
            if engine is not None:
                self._check_signing(engine, source)
                engine.activate(time.monotonic())
        if isinstance(payload, Engine):
            self._check_signing(engine, source)
        self.engine = engine
        self._hash = None if engine is None else engine.profile.content_hash()
        self._since = time.time()
        self._signed = {}  # the new profile may target what is not signed; the next frames tell
        self._warn(engine)
        self._tell()

    def _tell(self) -> None:
        for listener in self.listeners:
            listener()

    def _check_signing(self, engine: Engine | None, source: str) -> None:
        """Refuse (``InputError``) a profile that would write frames where the link signs and we have no key."""
        if engine is None or self.unkeyed is None:
            return
        signed = self.unkeyed()
        if not signed:
            return
        for i, kind, directions in needs_key(engine.profile):
            hit = sorted(directions & signed)
            if hit:
                raise InputError(source, f"rules[{i}]", kind, f"the {hit[0]} of vehicle {self.sysid} is signed and "
                                 "this proxy has no signing key: it cannot forge or rewrite frames there (start "
                                 "secuav-proxy with --signing-key FILE, docs/interfaces.md)")  # fmt: skip

    def _allowed(self, profile: Profile | None, source: str) -> None:
        """Every door (MQTT, the file reload, ``--profile``, an engine) passes here: with ``forbid_uplink`` a rule
        toward the vehicle is refused (``InputError`` naming it) before anything is installed."""
        if profile is not None and self.forbid_uplink:
            check_no_uplink(profile, source if profile.source == "<profile>" else profile.source)  # the file

    def _warn(self, engine: Engine | None) -> None:
        """Watch for the carriers the profile leaves true; say at once those the vehicle was already seen
        sending, and note once that rules toward the vehicle will be reported by it."""
        self._watch_carriers(engine)
        for tell in self.on_install:
            tell(self)

    def _watch_carriers(self, engine: Engine | None) -> None:
        self._directions = tuple(directions_of(None if engine is None else engine.profile))
        if engine is None:
            self._watch, self._ids, self._filters, self._memo = None, frozenset(), {}, {}
            return
        watch = self._watch = TrueCopyWatch(findings(engine.profile), self._sent)
        self._want(engine, watch)
        for warning in watch.warnings:
            log.warning("attack.true_copy", extra={"sysid": self.sysid, "profile": engine.profile.name,
                                                   "warning": warning})  # fmt: skip
        if self.announce:
            self.say_notes()

    def say_notes(self) -> None:
        """Say once per install that the autopilot will report what rules toward the vehicle feed it."""
        engine = self.engine
        for note in () if engine is None else vehicle_reports(engine.profile):
            log.info("attack.vehicle_reports", extra={"sysid": self.sysid, "profile": engine.profile.name,
                                                      "note": note})  # fmt: skip


def _less_watched(found: dict[int, _V], watch: TrueCopyWatch) -> dict[int, _V]:
    """``found`` less the carriers ``watch`` waits for; ``found`` itself when it holds none (same identity)."""
    if not found or not watch.message_ids & found.keys():
        return found
    return {msgid: f for msgid, f in found.items() if msgid not in watch.message_ids}


def signed_no_key(sysid: int, msgid: int) -> str:
    """The ``attack.signed_no_key`` warning: the frames of ``sysid`` are signed and the proxy cannot re-sign."""
    cls = codec.MAVLINK_MAP.get(msgid)
    what = f"message {msgid}" if cls is None else cls.msgname
    return (f"attack.signed_no_key: system {sysid} signs its frames ({what} among them) and this proxy has no "
            "signing key, so the profile leaves them as they are: start secuav-proxy with --signing-key FILE "
            "(docs/interfaces.md)")

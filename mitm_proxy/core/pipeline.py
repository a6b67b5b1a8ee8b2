"""One link's pipeline, sans I/O: datagram in, datagrams to send out.

    tap (split, count, record) -> stages in order (attack, secure; each may be
    bypassed) -> forward (re-pack what changed, keep the rest byte for byte)

The edge calls :meth:`Pipeline.feed` with each datagram and sends what comes
back: items whose ``release_s`` is not in the future at once, the others when
their time comes. A datagram none of whose frames a stage took and that held no
garbage comes back as the very same ``bytes`` object (the fast path: one split,
a set lookup per frame, nothing copied). Otherwise the frames that go out now
are joined, in their original order, into one datagram, and each delayed frame
is its own item.

Hostile input is bounded per second as well as per datagram (the endpoints drop
datagrams over 8 kB unread): once more than ``HOSTILE_BYTES_PER_S`` bytes of
datagrams holding garbage arrived in one direction within a second, a datagram
that is not back-to-back frames by its length fields (:func:`mavframe.frames.tiles`,
one step per frame) is dropped unsplit for the rest of that second and counted
under ``bad["over_budget"]``. A sender's frames always tile, so they still pass.

Observers (the recorder, a console's readings tap, any future one) attach with
:meth:`Pipeline.attach` and see the link through four hooks, :class:`Observer`:
frames in, after each stage, each frame out, each frame dropped. While one is
attached every datagram takes the slow path, where the hooks are called; with
none the fast path has nothing to call and pays one truth test.

A stage sees a frame only when it is active, the frame's message id is in its
``message_ids``, and the frame is not signed, unless the pipeline has the link's
signing key. A stage may narrow some of its ids to a few values of a one-byte id field
(``field_filters``, optional: ``msgid -> (field, values)``, e.g. the attack profile's
DISTANCE_SENSOR sensor ids): while every active stage that wants such an id narrows it on the
same field, an unsigned frame of it whose field holds none of the values is not wanted at all:
it passes as it came, byte for byte, undecoded, on the fast path (a field beyond a MAVLink 2
zero-truncated payload reads 0, as it decodes). A signed frame of such an id is wanted whole
(counted and told as below). A signed frame a stage wanted and did not get (no key) is counted
under ``signed_untouched``, handed to the stage's optional ``signed_untouched(header)``
(so its state can say it is inert) and logged once per stage and sending
system as ``<stage>.signed_no_key``. A stage that raises does not stop forwarding: the frame leaves as it
came, the error is counted under ``bad["stage_error"]`` and logged once.

A stage may also let the compiled fast path repeat its rewrites (``memo_fields``, optional: ``msgid ->`` the
name of the field a frame's key leaves out, its time field, or None; with ``memo_token``, an object that changes
whenever what it learnt may no longer hold). For an id that every active stage wanting it offers so, a frame
the stages passed on alone and undelayed, unsigned, whose packet a stage marked ``steady_until_s`` (monotonic)
is told, with the bytes it left as, to the direction's ``learners`` (the fast route's ``learn``:
mitm_proxy/README.md, "The fast path"); the route then rewrites frames with the same key, received before that
time, itself. Nothing is learnt while an observer is attached, the link has a signing key or the direction's
sequence numbers are watched.

Time-driven frames (an injection at a rate, a replayed recording) do not wait for traffic: a stage
that has them answers ``next_due_s()`` (monotonic, or None) and ``due(now_s, link)``, and the edge
calls :meth:`Pipeline.tick` when :meth:`Pipeline.next_tick_s` says, and only then (no timer while
nothing is scheduled). Every frame a stage adds, by ``process`` or ``due``, takes the next sequence
number of the source it impersonates and that source's later frames are renumbered
(:mod:`mitm_proxy.core.sequence`); a direction nobody forges in keeps no sequencer, so its fast path
pays one truth test. On a direction where signed frames arrived and the proxy has no key, forged
frames are not sent (a receiver that checks signatures would drop them): they are counted under
``signed_untouched`` and the stage is told (``signed_untouched``), as for a frame it could not rewrite.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from mavframe import codec
from mavframe.frames import TEXT, V1_HEADER_LEN, V2_HEADER_LEN, split, tiles
from mavframe.packet import Direction, Header, Packet
from mavframe.signing import SIGNATURE_LEN, Signer
from mitm_proxy.core.sequence import Sequencer
from mitm_proxy.core.stats import DirectionStats, LinkStats

__all__ = ["Observer", "Outgoing", "Pipeline", "Stage"]

log = logging.getLogger(__name__)

_NOTHING: frozenset[int] = frozenset()
_NO_FILTERS: dict[int, tuple[int, frozenset[int]]] = {}
_NO_MEMO: dict[int, tuple[int, int]] = {}
Learner = Callable[[bytes, bytes, float, bool], object]  # (frame in, bytes out, until monotonic s, counted a rewrite)
STAGE_ERROR = "stage_error"
ENCODE_ERROR = "encode_error"
OVER_BUDGET = "over_budget"
PRINTING_S = 10.0  # after printable lines from a sender, its short printable runs are text for this long
# Splitting crafted bytes runs at 2-6 MB/s (mavframe.frames): 256 kB of garbage a second costs at most
# about a tenth of a core before the cheap check takes over.
HOSTILE_BYTES_PER_S = 256 * 1024


class Stage(Protocol):
    """One step of the pipeline (tap, attack, secure).

    ``active`` False is the seed's bypass: the pipeline skips the stage.
    ``message_ids`` is the set of message ids the stage wants; the pipeline
    hands it nothing else, so untargeted traffic costs one set lookup.
    ``process`` returns the packets to pass on: ``[]`` drops, ``[pkt]`` passes
    (changed or not), extra packets are injected after it.

    Optional (see the module doc): ``next_due_s()``, ``due(now_s, link)`` for frames made on a
    clock, ``forges`` (the directions it may add frames to, so their sequence numbers are watched),
    ``field_filters`` (``msgid -> (field, values)``: of ``message_ids``, those wanted only when a
    frame's one-byte field holds one of the values; the same object while it stays the same), and
    ``memo_fields`` / ``memo_token`` (rewrites the fast path may repeat: the module doc).
    """

    name: str

    @property
    def active(self) -> bool: ...

    @property
    def message_ids(self) -> frozenset[int]: ...

    def process(self, pkt: Packet, now_s: float) -> list[Packet]: ...


class Observer(Protocol):
    """Watches one link's frames without changing them; the pipeline calls it on the slow path only.

    ``pos`` is a frame's position in its datagram (the frames :meth:`frames_in` was given);
    ``pkt`` is None for a frame no stage took (it leaves as ``raw``), else the packet that
    leaves (``pkt.injected`` for one a stage added); ``delay_s`` > 0 when a stage held it back.
    """

    def frames_in(self, direction: Direction, frames: Sequence[tuple[Header, bytes]]) -> None: ...

    def after_stage(self, stage: Stage, pkts: Sequence[Packet]) -> None: ...

    def frame_out(self, direction: Direction, pos: int, header: Header, raw: bytes, data: bytes,
                  pkt: Packet | None, delay_s: float) -> None: ...  # fmt: skip

    def dropped(self, direction: Direction, pos: int, header: Header, raw: bytes, pkt: Packet) -> None: ...


@dataclass(slots=True)
class _HostileBudget:
    """One direction's garbage in the current one-second window (see the module doc)."""

    window_s: float = -1.0  # when the window began
    spent: int = 0  # bytes of datagrams that held garbage since then
    over_until_s: float = -1.0  # until then, datagrams that are not whole frames are dropped unsplit
    printing_until_s: float = -1.0  # until then the sender counts as printing text (frames.split's ``printing``)


class Outgoing(NamedTuple):
    """Bytes for the other side; not to be sent before ``release_s`` (monotonic).

    ``rx_s`` is when the (first) frame in it arrived, for the latency figure;
    ``frames`` how many frames it holds. A named tuple because one is made per
    datagram on the hot path (a third of the cost of a frozen dataclass).
    """

    data: bytes
    release_s: float
    rx_s: float = 0.0
    frames: int = 1


class FastWants(NamedTuple):
    """What the compiled fast path takes from the pipeline for one direction (:meth:`Pipeline.fast_wanted`).

    ``ids``: the message ids whose frames must come through :meth:`Pipeline.feed`; ``filters``: those of
    them wanted only for a few values of a one-byte field (``msgid -> (payload offset, values)``); ``memo``:
    the ids whose rewrites the route may repeat (``msgid -> (offset, length)`` of the payload span a frame's
    key leaves out, ``(0, 0)``: none); ``token``: changes whenever what the route learnt may no longer hold.
    """

    ids: frozenset[int]
    filters: dict[int, tuple[int, frozenset[int]]]
    memo: dict[int, tuple[int, int]]
    token: tuple[object, ...]


class Pipeline:
    """Frames of one link (one vehicle) through ``stages``; see the module doc."""

    def __init__(
        self,
        link: int,
        stages: Sequence[Stage],
        *,
        stats: LinkStats,
        observers: Sequence[Observer] = (),
        signer: Signer | None = None,
    ) -> None:
        self.link = link
        self.stages: list[Stage] = list(stages)
        self.stats = stats
        self.observers: tuple[Observer, ...] = tuple(observers)
        self.signer = signer
        self._logged: set[str] = set()
        self._said_signed: set[tuple[str, int]] = set()  # (stage, sysid) told about a signed stream without the key
        self._union_key: tuple[object, ...] = ()
        self._union: frozenset[int] = _NOTHING
        self._filters: dict[int, tuple[int, frozenset[int]]] = _NO_FILTERS
        self._memo: dict[int, tuple[int, int]] = _NO_MEMO  # msgid -> the payload span its key leaves out
        # Direction -> the fast routes that repeat what the stages rewrite there (mitm_proxy.net.native_udp)
        self.learners: dict[Direction, list[Learner]] = {}
        self._budget = {d: _HostileBudget() for d in Direction}
        # Directions whose sequence numbers are watched (a stage forges there, or did): none, the usual case,
        # costs the fast path one truth test.
        self._seqs: dict[Direction, Sequencer] = {}

    def attach(self, observer: Observer) -> None:
        """From the next datagram on, ``observer`` sees every frame (see :class:`Observer`)."""
        if observer not in self.observers:
            self.observers = (*self.observers, observer)

    def detach(self, observer: Observer) -> None:
        self.observers = tuple(o for o in self.observers if o is not observer)

    def _wanted(self) -> tuple[list[Stage], frozenset[int], dict[int, tuple[int, frozenset[int]]]]:
        """Active stages, the union of their message ids and the field filters that narrow some of them
        (``msgid -> (payload offset, values)``), asked afresh per datagram (bypass and profile swaps take
        effect between two datagrams); union and filters are cached while the stages' sets stay the same."""
        active = [s for s in self.stages if s.active]
        if not active:
            return active, _NOTHING, _NO_FILTERS
        if len(active) == 1:  # the usual case, per datagram: no generator
            one = active[0]
            key: tuple[object, ...] = (one.message_ids, getattr(one, "field_filters", None),
                                       getattr(one, "memo_fields", None))  # fmt: skip
        else:
            key = tuple(x for s in active for x in (s.message_ids, getattr(s, "field_filters", None),
                                                     getattr(s, "memo_fields", None)))  # fmt: skip
        if key != self._union_key:
            self._union_key = key
            self._union = frozenset().union(*key[::3])
            self._filters = _merge_filters(active)
            self._memo = _merge_memo(active)
        return active, self._union, self._filters

    def fast_wanted(self, direction: Direction) -> FastWants | None:
        """For the compiled fast path (:mod:`mitm_proxy.net.native_udp`): what must come through :meth:`feed` on
        ``direction`` and what the route may repeat (:class:`FastWants`), or None when every frame must (an
        observer is attached, the link has a signing key, or the direction's sequence numbers are watched).
        Other frames, in datagrams of nothing but valid frames, are what :meth:`feed` would pass as they came,
        only counted."""
        if self.observers or self.signer is not None or direction in self._seqs:
            return None
        active, ids, filters = self._wanted()
        token = tuple(getattr(s, "memo_token", None) for s in active) if self._memo else ()
        return FastWants(ids, filters, self._memo, token)

    def _log_once(self, key: str, event: str, **extra: object) -> None:
        """Faults are counted per frame but logged once per kind, so a flood cannot flood the log."""
        if key not in self._logged:
            self._logged.add(key)
            log.warning(event, extra={"link": self.link, **extra})

    def _signed_untouched(self, header: Header, direction: Direction, active: list[Stage]) -> None:
        """A signed frame that ``active`` stages wanted passes as it came: tell them, and say it once, loudly.

        Runs for every such frame (a stage's state must learn it again after a profile swap), so the
        once-only log is keyed by a plain tuple, not a formatted string."""
        for stage in active:
            if header.msgid not in stage.message_ids:
                continue
            tell = getattr(stage, "signed_untouched", None)
            if tell is not None:
                tell(header)
            key = (stage.name, header.sysid)
            if key in self._said_signed:
                continue
            self._said_signed.add(key)
            log.warning(f"{stage.name}.signed_no_key", extra={
                "link": self.link, "sysid": header.sysid, "msgid": header.msgid, "direction": str(direction),
                "detail": f"system {header.sysid} signs its frames and this proxy has no signing key: the "
                          f"{stage.name} stage leaves them as they are (start secuav-proxy with --signing-key FILE, "
                          "docs/interfaces.md)"})  # fmt: skip

    def _spend(self, budget: _HostileBudget, size: int, direction: Direction, now_s: float) -> None:
        """Count a datagram that held garbage against this second's budget."""
        if now_s - budget.window_s >= 1.0:
            budget.window_s, budget.spent = now_s, 0
        budget.spent += size
        if budget.spent > HOSTILE_BYTES_PER_S:
            budget.over_until_s = budget.window_s + 1.0
            self._log_once(f"{OVER_BUDGET}:{direction}", "pipeline.over_budget", direction=str(direction),
                           detail=f"more than {HOSTILE_BYTES_PER_S} bytes of garbage in a second: until the second "
                           "ends, datagrams that are not whole frames are dropped unsplit")  # fmt: skip

    def feed(self, datagram: bytes, direction: Direction, now_s: float) -> list[Outgoing]:
        """Process one received datagram; return what to send to the other side."""
        st = self.stats.directions[direction]
        budget = self._budget[direction]
        if now_s < budget.over_until_s and not tiles(datagram):
            st.datagrams_in += 1
            st.bytes_in += len(datagram)
            st.add_bad(OVER_BUDGET)
            return []
        res = split(datagram, now_s < budget.printing_until_s)
        frames = res.frames
        st.datagrams_in += 1
        st.frames_in += len(frames)
        st.bytes_in += len(datagram)
        if res.unknown:
            st.unknown += res.unknown
        if res.bad:
            for reason in res.bad:
                st.add_bad(reason)
            if TEXT in res.bad:  # the sender prints (an autopilot's console): its short runs are text too
                budget.printing_until_s = now_s + PRINTING_S
            self._spend(budget, len(datagram), direction, now_s)
        active, wanted, filters = self._wanted()
        signer = self.signer
        slow = bool(res.bad) or bool(self.observers)
        for header, raw in frames:
            if header.signed:
                st.signed += 1
                if signer is not None:
                    slow = True
                elif header.msgid in wanted:
                    st.signed_untouched += 1
                    self._signed_untouched(header, direction, active)
            elif header.msgid in wanted and not (filters and _filtered_out(header, raw, filters)):
                slow = True
        if self._seqs and not slow:
            seqr = self._seqs.get(direction)
            if seqr is not None:
                slow = seqr.observe(frames)
        if not slow:
            if not frames:
                return []
            st.frames_out += len(frames)
            st.bytes_out += len(datagram)
            return [Outgoing(datagram, now_s, now_s, len(frames))]
        return self._slow(frames, direction, now_s, st, active, wanted, filters)

    def _slow(
        self,
        frames: list[tuple[Header, bytes]],
        direction: Direction,
        now_s: float,
        st: DirectionStats,
        active: list[Stage],
        wanted: frozenset[int],
        filters: dict[int, tuple[int, frozenset[int]]],
    ) -> list[Outgoing]:
        signer = self.signer
        observers = self.observers
        seqr = self._seqs.get(direction)
        learn = None if observers or seqr is not None or signer is not None else self.learners.get(direction)
        for o in observers:
            o.frames_in(direction, frames)
        now_parts: list[bytes] = []
        later: list[Outgoing] = []
        for pos, (header, raw) in enumerate(frames):
            if header.signed and signer is not None:
                reason = signer.verify(raw)
                if reason is not None:
                    st.add_bad(reason)
                    continue
            if (header.msgid not in wanted or (header.signed and signer is None) or
                    (filters and _filtered_out(header, raw, filters))):  # fmt: skip
                data = raw if seqr is None else self._renumber(header, raw, raw, seqr, st)
                now_parts.append(data)
                for o in observers:
                    o.frame_out(direction, pos, header, raw, data, None, 0.0)
                continue
            pkt = Packet(raw, header, direction, self.link, now_s)
            try:
                pkts = self._run_stages(pkt, active, now_s)
            except Exception as exc:  # a stage bug must not stop forwarding
                st.add_bad(STAGE_ERROR)
                self._log_once(
                    f"stage:{type(exc).__name__}", "pipeline.stage_error", msgid=header.msgid, error=repr(exc)
                )
                pkt = Packet(raw, header, direction, self.link, now_s)  # as it came, not half-changed
                pkts = [pkt]
            if not any(p is pkt for p in pkts):
                st.dropped += 1
                if seqr is not None:
                    seqr.dropped(header)
                for o in observers:
                    o.dropped(direction, pos, header, raw, pkt)
            for p in pkts:
                data = self._wire(p, st)
                if p.injected or self._seqs:  # forged: a number of its own; real: renumbered if its source is
                    data = self._sequence(p, data, st)
                delay_s = 0.0
                if p.release_s > now_s:
                    delay_s = p.release_s - now_s
                    st.delayed += 1
                    st.frames_out += 1
                    st.bytes_out += len(data)
                    later.append(Outgoing(data, p.release_s, p.rx_s, 1))
                else:
                    now_parts.append(data)
                    if learn and p is pkt and len(pkts) == 1:
                        self._learn(learn, p, data, now_s)
                for o in observers:
                    o.frame_out(direction, pos, header, raw, data, p, delay_s)
        out: list[Outgoing] = []
        if now_parts:
            joined = b"".join(now_parts)
            st.frames_out += len(now_parts)
            st.bytes_out += len(joined)
            out.append(Outgoing(joined, now_s, now_s, len(now_parts)))
        out.extend(later)
        return out

    def _learn(self, learners: list[Learner], p: Packet, data: bytes, now_s: float) -> None:
        """Tell the fast routes how this frame left, when the stages said it may be repeated (the module doc)."""
        until = p.steady_until_s
        if until is None or until <= now_s or p.header.msgid not in self._memo:  # (signed: learn is None)
            return
        if p.changed and data is p.raw:  # the re-pack failed (encode_error): that is Python's to count
            return
        for learner in learners:
            learner(p.raw, data, until, p.changed)

    def _run_stages(self, pkt: Packet, active: list[Stage], now_s: float) -> list[Packet]:
        signer = self.signer
        observers = self.observers
        pkts = [pkt]
        for stage in active:
            ids = stage.message_ids
            nxt: list[Packet] = []
            for p in pkts:
                if p.header.msgid in ids and (signer is not None or not p.header.signed):
                    nxt.extend(stage.process(p, now_s))
                else:
                    nxt.append(p)
            pkts = nxt
            for o in observers:
                o.after_stage(stage, pkts)
        return pkts

    def _wire(self, p: Packet, st: DirectionStats) -> bytes:
        """Bytes of one packet leaving the pipeline; counts rewrites and injections."""
        data = p.raw
        if p.changed:
            try:
                data = codec.encode(p, self.signer if p.header.signed else None)
            except codec.EncodeError as exc:  # e.g. a value out of the wire range: send it as it came
                st.add_bad(ENCODE_ERROR)
                self._log_once(
                    f"encode:{p.header.msgid}", "pipeline.encode_error", msgid=p.header.msgid, error=str(exc)
                )
                data = p.raw
            else:
                if not p.injected:
                    st.rewritten += 1
                if p.header.signed:
                    st.resigned += 1
        if p.injected:
            st.injected += 1
            if p.origin == "duplicate":
                st.duplicated += 1
            elif p.origin == "replay":
                st.replayed += 1
        return data

    def _sequence(self, p: Packet, data: bytes, st: DirectionStats) -> bytes:
        """Sequence number (and signature) of one packet leaving: see :mod:`mitm_proxy.core.sequence`."""
        seqr = self._seqs.get(p.direction)
        if not p.injected:
            return data if seqr is None else self._renumber(p.header, data, p.raw, seqr, st)
        if seqr is None:
            seqr = self._seqs[p.direction] = Sequencer()
        h = p.header
        data = codec.unsigned(data)  # a copy of a signed frame: the old signature would be a replay
        data = codec.restamp(data, seqr.forged(h.sysid, h.compid, data[4 if data[0] == 0xFD else 2]))
        if self.signer is not None:
            try:
                data = codec.sign_injected(data, self.signer)
            except codec.EncodeError as exc:  # not a v2 frame of a known id: it leaves unsigned
                st.add_bad(ENCODE_ERROR)
                self._log_once("sign_injected", "pipeline.sign_error", msgid=h.msgid, error=str(exc))
            else:
                st.resigned += 1
        return data

    def _renumber(self, h: Header, data: bytes, original: bytes, seqr: Sequencer, st: DirectionStats) -> bytes:
        """A real frame with the number its source's stream needs; signed ones only with the key."""
        seq = seqr.real(h)
        if seq == h.seq:
            return data
        if not h.signed:
            return codec.restamp(data, seq)
        if self.signer is None:
            return data  # cannot re-sign: it leaves as it came (forging there was refused or withheld)
        st.resigned += 1
        return self.signer.resign(codec.restamp(data[:-SIGNATURE_LEN], seq), original)

    # -- frames on a clock ------------------------------------------------------------------------

    def unkeyed_signed(self) -> frozenset[Direction]:
        """Directions where signed frames arrived and this proxy has no key to sign what it would add or change."""
        if self.signer is not None:
            return frozenset()
        return frozenset(d for d, s in self.stats.directions.items() if s.signed)

    def next_tick_s(self) -> float | None:
        """When :meth:`tick` has something to send (monotonic), or None; also starts watching the sequence
        numbers of every direction an active stage may forge in (and stops where nothing was forged)."""
        best: float | None = None
        forging: set[Direction] = set()
        for stage in self.stages:
            if not stage.active:
                continue
            forging |= getattr(stage, "forges", frozenset())
            ask = getattr(stage, "next_due_s", None)
            t = None if ask is None else ask()
            if t is not None and (best is None or t < best):
                best = t
        for d in forging:
            self._seqs.setdefault(d, Sequencer())
        for d in [d for d, seqr in self._seqs.items() if d not in forging and not seqr.offset]:
            del self._seqs[d]  # nothing renumbered there: the fast path is free again
        return best

    def tick(self, now_s: float) -> list[tuple[Direction, Outgoing]]:
        """What the stages' clocks have due at ``now_s``: one datagram per direction."""
        parts: dict[Direction, list[bytes]] = {}
        unkeyed = self.unkeyed_signed()
        for stage in self.stages:
            due = getattr(stage, "due", None)
            if due is None or not stage.active:
                continue
            try:
                pkts = due(now_s, self.link)
            except Exception as exc:  # a stage bug must not stop the link
                self._log_once(f"tick:{type(exc).__name__}", "pipeline.stage_error", error=repr(exc))
                continue
            for p in pkts:
                st = self.stats.directions[p.direction]
                if p.direction in unkeyed:
                    st.signed_untouched += 1
                    self._forge_withheld(stage, p)
                    continue
                data = self._sequence(p, self._wire(p, st), st)
                parts.setdefault(p.direction, []).append(data)
                for o in self.observers:
                    o.frames_in(p.direction, ())
                    o.frame_out(p.direction, 0, p.header, p.raw, data, p, 0.0)
        out: list[tuple[Direction, Outgoing]] = []
        for d, chunk in parts.items():
            st = self.stats.directions[d]
            joined = b"".join(chunk)
            st.frames_out += len(chunk)
            st.bytes_out += len(joined)
            out.append((d, Outgoing(joined, now_s, now_s, len(chunk))))
        return out

    def _forge_withheld(self, stage: Stage, p: Packet) -> None:
        tell = getattr(stage, "signed_untouched", None)
        if tell is not None:
            tell(p.header)
        self._log_once(f"forge_no_key:{p.direction}", f"{stage.name}.forge_no_key", direction=str(p.direction),
                       detail=f"the {p.direction} of this link is signed and this proxy has no signing key: frames "
                       "it would forge there are not sent (start secuav-proxy with --signing-key FILE)")  # fmt: skip


def _selected(header: Header, raw: bytes, flt: tuple[int, frozenset[int]]) -> bool:
    """Whether a frame's filtered one-byte field holds a wanted value (past a truncated payload it reads 0)."""
    offset, values = flt
    return (raw[(V2_HEADER_LEN if header.version == 2 else V1_HEADER_LEN) + offset]
            if offset < header.payload_len else 0) in values  # fmt: skip


def _filtered_out(header: Header, raw: bytes, filters: dict[int, tuple[int, frozenset[int]]]) -> bool:
    """Whether a field filter leaves this frame unwanted: unsigned (a signed one is wanted whole) and its
    filtered field holding none of the wanted values."""
    flt = filters.get(header.msgid)
    return flt is not None and not header.signed and not _selected(header, raw, flt)


def _merge_filters(active: Sequence[Stage]) -> dict[int, tuple[int, frozenset[int]]]:
    """The filters that hold for the pipeline: an id every active stage wanting it narrows on the same field,
    with the union of their values; an id one of them wants whole (or a field no one byte holds) is wanted whole."""
    merged: dict[int, tuple[int, frozenset[int]]] = {}
    whole: set[int] = set()
    for stage in active:
        found = getattr(stage, "field_filters", None) or {}
        for msgid in stage.message_ids:
            flt = found.get(msgid)
            offset = None if flt is None else codec.byte_field(msgid, flt[0])
            if offset is None:
                whole.add(msgid)
                continue
            values = frozenset(v for v in flt[1] if 0 <= v < 256)  # type: ignore[index]
            had = merged.get(msgid)
            if had is None:
                merged[msgid] = (offset, values)
            elif had[0] != offset:
                whole.add(msgid)
            else:
                merged[msgid] = (offset, had[1] | values)
    for msgid in whole:
        merged.pop(msgid, None)
    return merged or _NO_FILTERS


def _merge_memo(active: Sequence[Stage]) -> dict[int, tuple[int, int]]:
    """The ids whose rewrites the fast path may repeat: wanted by at least one active stage, and every active
    stage that wants one offers it in ``memo_fields`` with the same field left out of the key; each with that
    field's payload span (``(0, 0)``: the whole payload is the key)."""
    offered: dict[int, str | None] = {}
    refused: set[int] = set()
    for stage in active:
        found = getattr(stage, "memo_fields", None) or {}
        for msgid in stage.message_ids:
            if msgid not in found or offered.setdefault(msgid, found[msgid]) != found[msgid]:
                refused.add(msgid)
    out: dict[int, tuple[int, int]] = {}
    for msgid, name in offered.items():
        if msgid in refused:
            continue
        span = (0, 0) if name is None else codec.field_span(msgid, name)
        if span is not None:
            out[msgid] = span
    return out or _NO_MEMO

"""frame_replay: record whole frames during a window and send them again later (a replay attack).

Unlike ``replay``, which puts old *values* into the frames that pass (the stream keeps its own
frames, timestamps and rate), ``frame_replay`` sends the recorded *frames* themselves again, as extra
frames, with their original spacing: a replayed command is obeyed twice, a replayed mission item
arrives again. Recorded frames keep their content; each takes the next sequence number of its sender.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from attack_profiles.primitives.frame_op import FrameOp, FrameOpRule, LinkView, codec_module
from attack_profiles.rule import Seconds
from mavframe.packet import Packet
from secuav_common.loading import InputError

MAX_FRAMES = 10_000  # recorded per vehicle; bounds memory however fast the target streams
MAX_PER_TICK = 1_000  # a late timer sends what is due, but never more than this at once


class FrameReplayRule(FrameOpRule):
    """Record the frames of ``target.message`` in ``target.direction`` while ``record_start_s <= t <
    record_end_s``; from ``start_s`` send them again, spaced as they came (the first at ``start_s``), once,
    or with ``loop`` over and over (a period is the recording window's length) until ``end_s``. With
    ``replace`` the live frames of the target are dropped while the recording plays (``start_s`` to
    ``end_s``, or the end of a single playback)."""

    kind: Literal["frame_replay"] = "frame_replay"
    record_start_s: Seconds = Field(description="recording begins (profile clock)")
    record_end_s: Seconds = Field(description="recording ends; at or before start_s")
    loop: bool = Field(False, description="play the recording over and over until end_s")
    replace: bool = Field(False, description="drop the live frames of the target while it plays")

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.record_end_s <= self.record_start_s:
            raise InputError(source, f"{where}.record_end_s", self.record_end_s, "recording ends before it starts")
        if self.record_end_s > self.start_s:
            raise InputError(source, f"{where}.record_end_s", self.record_end_s,
                             f"plays back what is not recorded yet: playback starts at {self.start_s}")  # fmt: skip


class FrameReplay(FrameOp):
    kind = "frame_replay"
    rule_model = FrameReplayRule

    def __init__(self, rule: FrameReplayRule, ctx: Any) -> None:
        super().__init__(rule, ctx)
        self.rec_start, self.rec_end = rule.record_start_s, rule.record_end_s
        self.period_s = rule.record_end_s - rule.record_start_s
        self.loop, self.replace = rule.loop, rule.replace
        self.recorded: dict[int, list[tuple[float, Packet]]] = {}  # vehicle -> (time since the first, frame)
        self._first: dict[int, float] = {}
        self._played: dict[int, int] = {}  # vehicle -> frames sent so far (all loops)

    def on_frame(self, pkts: list[Packet], t_s: float, view: LinkView) -> list[Packet]:
        out = pkts
        for p in pkts:
            if p.injected or not self.applies(p, view):
                continue
            if self.rec_start <= t_s < self.rec_end:
                rec = self.recorded.setdefault(view.vehicle, [])
                if len(rec) < MAX_FRAMES:
                    first = self._first.setdefault(view.vehicle, t_s)
                    frame = Packet(codec_module().unsigned(p.raw), p.header, p.direction, p.link, p.rx_s, injected=True,
                                   notes=[self.note], origin="replay")  # fmt: skip
                    rec.append((t_s - first, frame))
                    if len(rec) == 1:
                        view.rescheduled = True  # something to play now: the proxy's timer must know
            elif self.replace and self._playing(t_s, view.vehicle):
                out = [q for q in out if q is not p]
        return out

    def _playing(self, t_s: float, vehicle: int) -> bool:
        if not self.start_s <= t_s < self.end_s:
            return False
        rec = self.recorded.get(vehicle)
        if not rec:
            return False
        return self.loop or t_s <= self.start_s + rec[-1][0]

    def _at(self, vehicle: int, k: int) -> float:
        """Profile time of the ``k``-th frame sent (over every loop)."""
        rec = self.recorded[vehicle]
        lap, i = divmod(k, len(rec))
        return self.start_s + lap * max(self.period_s, rec[-1][0]) + rec[i][0]

    def next_due(self, view: LinkView) -> float | None:
        rec = self.recorded.get(view.vehicle)
        if not rec:
            return None
        k = self._played.get(view.vehicle, 0)
        if k >= len(rec) and not self.loop:
            return None
        t = self._at(view.vehicle, k)
        return t if t < self.end_s else None

    def due(self, t_s: float, view: LinkView, now_s: float) -> list[Packet]:
        out: list[Packet] = []
        while len(out) < MAX_PER_TICK:
            at = self.next_due(view)
            if at is None or at > t_s:
                break
            k = self._played.get(view.vehicle, 0)
            rec = self.recorded[view.vehicle]
            src = rec[k % len(rec)][1]
            out.append(Packet(src.raw, src.header, src.direction, view.link, now_s, injected=True,
                              notes=list(src.notes), origin="replay"))  # fmt: skip
            self._played[view.vehicle] = k + 1
        return out

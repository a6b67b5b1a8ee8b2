"""duplicate: every targeted frame arrives n + 1 times (a flaky radio, or a command said twice)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from attack_profiles.primitives.frame_op import FrameOp, FrameOpRule, LinkView
from mavframe.packet import Packet


class DuplicateRule(FrameOpRule):
    """While the window is open, each frame of ``target.message`` in ``target.direction`` is followed at
    once by ``copies`` copies of it (as it leaves, after the rules before this one). Each copy takes the
    next sequence number of its sender, so the receiver sees the same message again, not a repeated frame
    (a receiver that drops repeated sequence numbers would drop a byte-identical copy)."""

    kind: Literal["duplicate"] = "duplicate"
    copies: Annotated[int, Field(ge=1, le=10)] = Field(1, description="extra copies of each frame")


class Duplicate(FrameOp):
    kind = "duplicate"
    rule_model = DuplicateRule

    def __init__(self, rule: DuplicateRule, ctx: Any) -> None:
        super().__init__(rule, ctx)
        self.copies = rule.copies

    def on_frame(self, pkts: list[Packet], t_s: float, view: LinkView) -> list[Packet]:
        if not self.start_s <= t_s < self.end_s:
            return pkts
        out: list[Packet] = []
        for p in pkts:
            out.append(p)
            if p.injected or not self.applies(p, view):
                continue
            for _ in range(self.copies):
                copy = Packet(p.raw, p.header, p.direction, p.link, p.rx_s,
                              fields=None if p.fields is None else dict(p.fields), changed=p.changed, injected=True,
                              release_s=p.release_s, notes=[*p.notes, self.note], origin="duplicate")  # fmt: skip
                out.append(copy)
            view.counts[self.kind] = view.counts.get(self.kind, 0) + self.copies
        return out

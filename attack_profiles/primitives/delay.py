"""delay: the target's frames arrive late (PX4 "delayed", ArduPilot SIM_*_DELAY)."""

from __future__ import annotations

from collections import deque
from typing import Annotated, ClassVar, Literal

from pydantic import Field

from attack_profiles.primitives.base import TIME_EPS_S, Context, Primitive, Sample, SampleKey
from attack_profiles.rule import RuleBase


class DelayRule(RuleBase):
    """Hold matching frames back ``delay_s``. Live, the proxy sends the frame that much later
    (its fields unchanged, so its own timestamp shows the age). Offline, the sample at ``t``
    carries the value the target had at ``t - delay_s`` (NaN if there was none yet)."""

    kind: Literal["delay"] = "delay"
    frame_level: ClassVar[bool] = True
    delay_s: Annotated[float, Field(gt=0.0, le=60.0, allow_inf_nan=False)]


class Delay(Primitive):
    kind = "delay"
    rule_model = DelayRule
    stateful = True  # offline it must remember the stream before the window

    def __init__(self, rule: DelayRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.delay_s = rule.delay_s
        self.history: dict[SampleKey, deque[tuple[float, float]]] = {}

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if not s.offline:
            if tau_s is not None:
                s.delay_s += self.delay_s
            return
        hist = self.history.get(s.key)
        if hist is None:
            hist = self.history[s.key] = deque()
        hist.append((s.t_s, s.value))
        if tau_s is None:
            return
        cutoff = s.t_s - self.delay_s + TIME_EPS_S
        # Keep only the newest sample at or before the cutoff and everything after it.
        while len(hist) > 1 and hist[1][0] <= cutoff:
            hist.popleft()
        s.value = hist[0][1] if hist[0][0] <= cutoff else float("nan")

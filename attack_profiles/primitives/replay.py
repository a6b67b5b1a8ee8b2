"""replay: play back what the target reported during an earlier window, in a loop."""

from __future__ import annotations

from bisect import bisect_right
from typing import Literal

from attack_profiles.primitives.base import TIME_EPS_S, Context, Primitive, Sample, SampleKey
from attack_profiles.rule import RuleBase, Seconds
from secuav_common.loading import InputError

MAX_RECORDED = 100_000  # per target; bounds memory if a source window is long and the rate high


class ReplayRule(RuleBase):
    """Record the target's values while ``source_start_s <= t < source_end_s`` (profile clock),
    then inside the window output the recording, looped: at ``tau`` the value recorded at
    ``source_start_s + tau mod (source_end_s - source_start_s)``. The source window must
    end by the time the rule starts. Until something was recorded, values pass unchanged."""

    kind: Literal["replay"] = "replay"
    source_start_s: Seconds
    source_end_s: Seconds

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.source_end_s <= self.source_start_s:
            raise InputError(source, f"{where}.source_end_s", self.source_end_s, "source window ends before it starts")
        if self.source_end_s > self.start_s:
            raise InputError(
                source, f"{where}.source_end_s", self.source_end_s, f"replays the future: rule starts at {self.start_s}"
            )


class Replay(Primitive):
    kind = "replay"
    rule_model = ReplayRule
    stateful = True

    def __init__(self, rule: ReplayRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.src_start = rule.source_start_s
        self.src_end = rule.source_end_s
        self.src_len = rule.source_end_s - rule.source_start_s
        self.times: dict[SampleKey, list[float]] = {}
        self.values: dict[SampleKey, list[float]] = {}

    def apply(self, s: Sample, tau_s: float | None) -> None:
        if self.src_start <= s.t_s < self.src_end:
            times = self.times.setdefault(s.key, [])
            if len(times) < MAX_RECORDED:
                times.append(s.t_s)
                self.values.setdefault(s.key, []).append(s.value)
        if tau_s is None:
            return
        times = self.times.get(s.key)
        if not times:
            return
        src_t = self.src_start + tau_s % self.src_len + TIME_EPS_S
        i = bisect_right(times, src_t) - 1
        s.value = self.values[s.key][max(i, 0)]

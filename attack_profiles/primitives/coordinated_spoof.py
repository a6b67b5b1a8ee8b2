"""coordinated_spoof: anchor ranges consistent with a fake position drifting off the true one.

For UWB anchor links (DISTANCE_SENSOR ids 10+k, anchor positions from the
scenario) the attacked ranges become exactly the distances from a fake position

    p_fake(tau) = M(p_true(t)) + offset_ned_m + velocity_ned_m_s * tau

to each attacked anchor, plus ``noise_std_m`` of Gaussian noise (what real
ranges carry, so the spoofed ones do not stand out by being too clean). ``M``
is the identity, or with ``mirror_ne_m`` (two points on a line in the
north-east plane) the reflection across that line: the colluding worst case,
where the fake position is the mirror image of the true one across the line
through two honest anchors, which agree with both. Every attacked range then agrees with one position, so
a residual test over the attacked links alone sees nothing wrong: the hardest
case for a secure estimator, which has to notice that the attacked set and the
clean set disagree.

Where ``p_true`` comes from: the sample's ``position_ned_m``, the position the
attacker reads (live: the latest LOCAL_POSITION_NED the same vehicle sent; on
the array path what the caller passes, the vehicle's own estimate in the
evaluation). Until one has been seen, ranges pass unchanged.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import Field

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.rule import Finite, RuleBase, Vec3Param
from secuav_common.loading import (
    _MISSING,  # the "no value to show" sentinel InputError understands
    InputError,
)
from secuav_common.sensor_ids import ANCHOR_BASE, MAX_ANCHORS


class CoordinatedSpoofRule(RuleBase):
    """Target: DISTANCE_SENSOR ``current_distance`` of anchor links (ids 10-49). Needs a scenario."""

    kind: Literal["coordinated_spoof"] = "coordinated_spoof"
    needs_position: ClassVar[bool] = True
    needs_anchors: ClassVar[bool] = True
    velocity_ned_m_s: Vec3Param = (0.0, 0.0, 0.0)
    offset_ned_m: Vec3Param = (0.0, 0.0, 0.0)
    mirror_ne_m: tuple[tuple[Finite, Finite], tuple[Finite, Finite]] | None = None
    noise_std_m: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 0.0

    def check(self, where: str, source: str) -> None:
        super().check(where, source)
        if self.mirror_ne_m is not None and self.mirror_ne_m[0] == self.mirror_ne_m[1]:
            raise InputError(source, f"{where}.mirror_ne_m", self.mirror_ne_m, "two distinct points make the line")
        target = self.target
        field = target.field or "current_distance"
        if target.message != "DISTANCE_SENSOR" or field != "current_distance":
            raise InputError(
                source, f"{where}.target", f"{target.message}.{field}", "must be DISTANCE_SENSOR.current_distance"
            )
        ids = target.sensor_ids()
        if ids is None:
            raise InputError(source, f"{where}.target.sensor_id", _MISSING, "name the attacked anchor links (10-49)")
        for sid in sorted(ids):
            if not ANCHOR_BASE <= sid < ANCHOR_BASE + MAX_ANCHORS:
                raise InputError(source, f"{where}.target.sensor_id", sid, "not an anchor link (ids 10-49)")


class CoordinatedSpoof(Primitive):
    kind = "coordinated_spoof"
    rule_model = CoordinatedSpoofRule

    def __init__(self, rule: CoordinatedSpoofRule, ctx: Context) -> None:
        super().__init__(rule, ctx)
        self.velocity = rule.velocity_ned_m_s
        self.offset = rule.offset_ned_m
        self.anchors = ctx.anchors_ned_m
        self.mirror = rule.mirror_ne_m
        self.noise = rule.noise_std_m
        self.rng = ctx.rng

    def fake_position(self, true_pos: tuple[float, float, float], tau_s: float) -> tuple[float, float, float]:
        v, o = self.velocity, self.offset
        n, e = true_pos[0], true_pos[1]
        if self.mirror is not None:  # reflect (n, e) across the line through the two points
            (n1, e1), (n2, e2) = self.mirror
            dn, de = n2 - n1, e2 - e1
            k = ((n - n1) * dn + (e - e1) * de) / (dn * dn + de * de)
            fn, fe = n1 + k * dn, e1 + k * de  # foot of the perpendicular
            n, e = 2.0 * fn - n, 2.0 * fe - e
        return (n + o[0] + v[0] * tau_s, e + o[1] + v[1] * tau_s, true_pos[2] + o[2] + v[2] * tau_s)

    def apply(self, s: Sample, tau_s: float | None) -> None:
        true_pos = s.position_ned_m
        anchor = self.anchors.get(s.key[1])
        if true_pos is None or anchor is None:
            return
        p = self.fake_position(true_pos, tau_s)  # type: ignore[arg-type]
        s.value = math.sqrt((p[0] - anchor[0]) ** 2 + (p[1] - anchor[1]) ** 2 + (p[2] - anchor[2]) ** 2)
        if self.noise > 0.0:
            s.value += self.rng.gauss(0.0, self.noise)

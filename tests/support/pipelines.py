"""A pipeline with one attack stage, built as the proxy builds it, and the profiles the pipeline tests offer it."""

from __future__ import annotations

from typing import Any

from attack_profiles.profile import parse_profile
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot


def profile(*rules: dict[str, Any]) -> Any:
    return parse_profile({"name": "t", "rules": list(rules)}, "t.yaml")


def bias(sensor_id: int = 0, offset_m: float = 2.0, **kw: Any) -> dict[str, Any]:
    return {
        "target": {"message": "DISTANCE_SENSOR", "sensor_id": sensor_id, **kw},
        "kind": "bias",
        "offset_m": offset_m,
    }


def make(*rules: dict[str, Any], extra: list[Any] | None = None) -> tuple[Pipeline, LinkStats, AttackStage]:
    slot = AttackSwitch(AttackSlot(1))
    if rules:
        slot.offer(profile(*rules))
    stage = AttackStage(slot.slot)
    stats = LinkStats(1)
    return Pipeline(0, [stage, *(extra or [])], stats=stats), stats, stage

"""What the secure stage tells the world: the ``secuav/v<N>/estimate`` payload and its counters.

Both are plain JSON data; NaN travels as null (docs/interfaces.md lists the fields).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from mitm_proxy.stages.secure.geodesy import position_ned
from mitm_proxy.stages.secure.layout import Layout
from mitm_proxy.stages.secure.worker import Stepper, StepResult


@dataclass(slots=True)
class Counters:
    frames_seen: int = 0
    substituted_frames: int = 0
    flagged_frames: int = 0
    readings_taken: int = 0  # DISTANCE_SENSOR readings of the group put into the vector
    sets_complete: int = 0
    sets_timed_out: int = 0
    decode_errors: int = 0
    published: int = 0
    signed_untouched: int = 0  # signed frames of the group the pipeline left alone (no key)


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def flagged_ids(layout: Layout, res: StepResult, peer_flagged: set[int]) -> list[int]:
    """Wire ids of the sensors judged attacked: the estimator's, and the peer ranges found off."""
    return sorted([*(layout.sensor_ids[i] for i in res.attacked_idx), *peer_flagged])


def estimate_payload(sysid: int, estimator: str | None, layout: Layout, res: StepResult,
                     peer_flagged: set[int]) -> dict[str, Any]:  # fmt: skip
    """``secuav/v<sysid>/estimate``."""
    est = res.estimate
    payload: dict[str, Any] = {
        "sysid": sysid,
        "estimator": estimator,
        "group": layout.group,
        "sim_t_s": res.job.sim_t_s,
        "rx_s": res.job.rx_s,
        "time_s": time.time(),
        "ok": est.ok,
        "alarm": est.alarm,
        "valid": est.valid,
        "attacked": flagged_ids(layout, res, peer_flagged),
        "used": sorted(layout.sensor_ids[i] for i in est.used),
        "step_time_s": est.step_time_s,
        "readings_m": [_num(v) for v in res.job.z],
        "sensor_ids": list(layout.sensor_ids),
    }
    if layout.position_dims:
        payload["position_ned_m"] = [_num(v) for v in position_ned(layout, res)]
    else:
        payload["distance_m"] = _num(est.position_m[0])
    return payload


def stage_stats(active: bool, estimator: str | None, executor: str, layout: Layout | None, stepper: Stepper | None,
                counters: Counters, peer_flagged: set[int]) -> dict[str, Any]:  # fmt: skip
    """Counters for ``secuav/v<sysid>/stats`` and the logs."""
    c, st = counters, stepper
    res = st.latest() if st is not None else None
    return {
        "active": active,
        "estimator": estimator,
        "group": None if layout is None else layout.group,
        "executor": executor,
        "threaded": None if st is None else st.threaded,
        "executor_switches": 0 if st is None else st.switches,
        "step_time_ewma_s": None if st is None else st.step_ewma_s,
        "steps": 0 if st is None else st.steps,
        "dropped_steps": 0 if st is None else st.dropped,
        "overruns": 0 if st is None else st.overruns,
        "step_errors": 0 if st is None else st.errors,
        "last_step_time_s": None if res is None else res.estimate.step_time_s,
        "sets_complete": c.sets_complete,
        "sets_timed_out": c.sets_timed_out,
        "readings": c.readings_taken,
        "frames_seen": c.frames_seen,
        "substituted_frames": c.substituted_frames,
        "flagged_frames": c.flagged_frames,
        "flagged_sensors": [] if res is None or layout is None else flagged_ids(layout, res, peer_flagged),
        "alarm": None if res is None else res.estimate.alarm,
        "decode_errors": c.decode_errors,
        "published": c.published,
        "signed_untouched": c.signed_untouched,
    }

"""A recording (a MAVLink .tlog or a recorded-ranges CSV, optional truth) framed into the streams a trial reads.

Shared by ``secuav-eval --tlog/--ranges`` and by study cells with a ``recording:``; see
:mod:`evaluation.tlog` and :mod:`evaluation.ranges` for the two inputs and how they are framed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from estimators.scenario_models import anchor_model, wall_group_model
from evaluation.ranges import read_ranges_csv
from evaluation.streams import VehicleStream
from evaluation.tlog import LogSummary, frame_rate_hz, log_streams, read_tlog, read_truth_csv
from evaluation.trial import RATE_HZ
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario


@dataclass(frozen=True, eq=False)
class Recorded:
    streams: dict[int, VehicleStream]
    info: LogSummary
    rows_skipped: int
    rate_hz: float
    boot_offset_s: float


def model_ids(scenario: Scenario) -> tuple[int, ...]:
    first = scenario.vehicles[0]
    if scenario.kind == "wall":
        return wall_group_model(scenario, first.sysid).ids()
    return anchor_model(scenario, first.sysid).ids()


def load_recording(
    scenario: Scenario,
    *,
    tlog: Path | None = None,
    ranges: Path | None = None,
    truth: Path | None = None,
    rate_hz: float | None = None,
) -> Recorded:
    """Read and frame one recording for ``scenario``; ``InputError`` names the file and field at fault."""
    source = tlog if tlog is not None else ranges
    if source is None:
        raise InputError("recording", "", None, "give a .tlog or a ranges CSV")
    skipped = 0
    needed = [v.sysid for v in scenario.vehicles[: 2 if scenario.kind == "formation" else 1]]
    down = {
        s: next((r.id for r in scenario.vehicle(s).sensors.rangefinders if r.orientation == "down"), None)
        for s in needed
    }
    if tlog is not None:
        logs, info = read_tlog(tlog)
    else:
        assert ranges is not None
        logs, info, skipped = read_ranges_csv(ranges, needed[0], down)
    truth_rows = None if truth is None else read_truth_csv(truth)
    absent = [s for s in needed if s not in logs]
    if absent:
        reason = f"scenario {scenario.name!r} needs sysid {absent[0]}; the log has {list(info.sysids)}"
        raise InputError(str(source), "sysid", absent[0], reason)
    if truth_rows is not None and needed[0] not in truth_rows:
        raise InputError(str(truth), "sysid", needed[0], f"no truth rows for it (has {sorted(truth_rows)})")
    rate = rate_hz or frame_rate_hz(logs[needed[0]], RATE_HZ)
    streams, boot_offset_s = log_streams(logs, needed, down, rate, truth_rows)
    wanted = set(model_ids(scenario))
    if not wanted & set(streams[needed[0]].readings):
        has = list(info.sensor_ids[needed[0]])
        reason = f"none of the scenario's sensor ids {sorted(wanted)} is in the log (it has {has})"
        raise InputError(str(source), "DISTANCE_SENSOR.id" if tlog is not None else "sensor_id", None, reason)
    return Recorded(streams, info, skipped, rate, boot_offset_s)

"""Recorded ranges in a plain CSV file (docs/recorded-ranges.md), the same streams a .tlog gives.

One row per reading, a header naming the columns (any order, others ignored)::

    t_s,sysid,sensor_id,range_m
    0.000,1,10,3.981
    0.000,1,11,1.310

``t_s`` seconds on one clock for the whole file (the truth CSV's, if one is given), ``sensor_id``
the wire id (docs/interfaces.md: 0-9 rangefinders, 10 + k anchor k, 50 + n peer sysid n),
``range_m`` metres; an empty ``range_m``, ``nan`` or a negative value is a missing reading (kept
as NaN, counted). ``sysid`` may be left out: every row is then the scenario's first vehicle. A
row whose time, sysid or sensor id is not a number is counted and skipped, the rest flows; a
file without the needed columns or without one good row is refused with one line naming it.
Anchor positions and the noise come from the scenario, as for a .tlog.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from evaluation.tlog import LogSummary, VehicleLog
from secuav_common.loading import InputError
from secuav_common.sensor_ids import ORIENTATION_DOWN

COLUMNS = ("t_s", "sensor_id", "range_m")


def _number(text: str | None) -> float:
    if text is None or not text.strip():
        raise ValueError("empty")
    return float(text)


def read_ranges_csv(
    path: Path, default_sysid: int, down_ids: dict[int, int | None] | None = None
) -> tuple[dict[int, VehicleLog], LogSummary, int]:
    """Per sysid the readings in file order; the summary; the number of rows skipped as unreadable.

    ``down_ids`` marks each vehicle's downward rangefinder (from the scenario), so it is framed as
    the height, like a .tlog's DISTANCE_SENSOR with the downward orientation."""
    if not path.is_file():
        raise InputError(str(path), "--ranges", str(path), "no such file")
    logs: dict[int, VehicleLog] = {}
    rows = skipped = missing = 0
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        have = reader.fieldnames or []
        absent = [c for c in COLUMNS if c not in have]
        if absent:
            reason = f"missing column (need {', '.join(COLUMNS)}; sysid optional); the header has {have}"
            raise InputError(str(path), absent[0], None, reason)
        with_sysid = "sysid" in have
        for rec in reader:
            rows += 1
            try:
                t_s = _number(rec["t_s"])
                sid = int(_number(rec["sensor_id"]))
                sysid = int(_number(rec["sysid"])) if with_sysid else default_sysid
                if not math.isfinite(t_s):
                    raise ValueError("time")
            except (TypeError, ValueError):
                skipped += 1
                continue
            text = (rec.get("range_m") or "").strip()
            try:
                value = float(text) if text else math.nan
            except ValueError:
                value = math.nan
            if not value >= 0.0:
                value = math.nan
                missing += 1
            log = logs.setdefault(sysid, VehicleLog(sysid))
            log.readings[sid].append((t_s, value))
    if not logs:
        raise InputError(str(path), "rows", rows, f"no readable row ({skipped} skipped)")
    for sysid, log in logs.items():
        down = (down_ids or {}).get(sysid)
        for sid in log.readings:
            log.orientation[sid] = ORIENTATION_DOWN if sid == down else 0
    summary = LogSummary(
        path=str(path),
        frames_read=rows - skipped,
        sysids=tuple(sorted(logs)),
        sensor_ids={s: tuple(sorted(v.readings)) for s, v in sorted(logs.items())},
        invalid_readings=missing,
    )
    return logs, summary, skipped

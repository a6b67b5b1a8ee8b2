"""Measurement streams from a recorded MAVLink telemetry log (.tlog) and optional ground truth.

A .tlog is what QGroundControl, MAVProxy and our recorder write: per frame an
8-byte big-endian wall-clock timestamp in microseconds, then the MAVLink frame
(read with :mod:`mavframe.tlog`, CRC-checked). We take, per vehicle (sysid):

- DISTANCE_SENSOR (#132): ``current_distance`` cm -> metres, keyed by sensor id
  (0-9 rangefinders, 10 + k anchor k, 50 + n peer sysid n:
  docs/interfaces.md#mavlink-mapping-mavlink-2-common-dialect). A reading
  outside ``[min_distance, max_distance]`` (PX4 drivers' "no target") or with
  ``signal_quality`` 1 ("invalid") is missing (NaN), never zero.
- LOCAL_POSITION_NED (#32): the autopilot's own position estimate, kept as a
  reference to compare against when no ground truth is given (it is NOT truth).

Time is the vehicle's boot clock (``time_boot_ms``), not the log's wall-clock
stamps: a simulator run faster than real time still gives sim seconds, and
flightsim's truth CSV (``secuav-sim --truth-csv``) carries the same clock, so
the two join on it. Readings are framed like the synthetic streams
(:mod:`evaluation.streams`): frame k at ``t_k = t_first + k / rate`` holds, per
sensor id, the last reading in ``(t_k - 1 / rate, t_k]``.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evaluation.streams import VehicleStream
from mavframe import codec
from mavframe import tlog as mavframe_tlog
from mavframe.packet import Direction, Packet
from secuav_common.loading import InputError
from secuav_common.sensor_ids import ANCHOR_BASE, ORIENTATION_DOWN, QUALITY_INVALID

TRUTH_COLUMNS = ("t_s", "sysid", "north_m", "east_m", "down_m")
_DISTANCE_SENSOR, _LOCAL_POSITION_NED = codec.message_id("DISTANCE_SENSOR"), codec.message_id("LOCAL_POSITION_NED")


@dataclass
class VehicleLog:
    """One vehicle's raw readings from a log, in arrival order."""

    sysid: int
    readings: dict[int, list[tuple[float, float]]] = field(default_factory=lambda: defaultdict(list))
    orientation: dict[int, int] = field(default_factory=dict)
    local_ned: list[tuple[float, float, float, float]] = field(default_factory=list)  # t_s, n, e, d


@dataclass(frozen=True)
class LogSummary:
    """What was in the file (for results.json and the user)."""

    path: str
    frames_read: int
    sysids: tuple[int, ...]
    sensor_ids: dict[int, tuple[int, ...]]  # per sysid
    invalid_readings: int


def read_tlog(path: Path) -> tuple[dict[int, VehicleLog], LogSummary]:
    """Read DISTANCE_SENSOR and LOCAL_POSITION_NED per sysid; InputError if none are there."""
    if not path.is_file():
        raise InputError(str(path), "--tlog", str(path), "no such file")
    logs: dict[int, VehicleLog] = {}
    frames = invalid = 0
    reader = mavframe_tlog.read(path)
    for entry in reader:
        header = entry.header
        if header.msgid not in (_DISTANCE_SENSOR, _LOCAL_POSITION_NED):
            continue
        msg = codec.decode(Packet(entry.raw, header, Direction.DOWNLINK, 0, entry.t_s))
        frames += 1
        log = logs.setdefault(header.sysid, VehicleLog(header.sysid))
        t_s = msg["time_boot_ms"] * 1e-3
        if header.msgid == _LOCAL_POSITION_NED:
            log.local_ned.append((t_s, msg["x"], msg["y"], msg["z"]))
            continue
        cm = msg["current_distance"]
        if cm < msg["min_distance"] or cm > msg["max_distance"] or msg["signal_quality"] == QUALITY_INVALID:
            value = math.nan
            invalid += 1
        else:
            value = cm * 0.01
        log.readings[msg["id"]].append((t_s, value))
        log.orientation[msg["id"]] = msg["orientation"]
    logs = {s: v for s, v in logs.items() if v.readings}
    if not logs:
        raise InputError(str(path), "DISTANCE_SENSOR", None, "no range readings in this log (is it a MAVLink .tlog?)")
    summary = LogSummary(
        path=str(path),
        frames_read=frames,
        sysids=tuple(sorted(logs)),
        sensor_ids={s: tuple(sorted(v.readings)) for s, v in sorted(logs.items())},
        invalid_readings=invalid,
    )
    return logs, summary


def frame_rate_hz(log: VehicleLog, default_hz: float) -> float:
    """The range sensors' own rate: median spacing of the busiest non-downward sensor (else ``default_hz``)."""
    candidates = [i for i in log.readings if log.orientation.get(i) != ORIENTATION_DOWN]
    if not candidates:
        return default_hz
    busiest = max(candidates, key=lambda i: len(log.readings[i]))
    t = np.array([r[0] for r in log.readings[busiest]])
    gaps = np.diff(np.unique(t))
    if gaps.size < 3:
        return default_hz
    return float(1.0 / np.median(gaps))


def frame_times(logs: list[VehicleLog], rate_hz: float) -> np.ndarray:
    """Frame ends on the boot clock, from the first anchor/peer reading to the last reading of any vehicle."""
    starts, ends = [], []
    for log in logs:
        for sid, rows in log.readings.items():
            if log.orientation.get(sid) == ORIENTATION_DOWN:
                continue
            starts.append(min(r[0] for r in rows))
            ends.append(max(r[0] for r in rows))
    if not starts:
        raise InputError("--tlog", "DISTANCE_SENSOR", None, "only downward rangefinders in this log")
    period = 1.0 / rate_hz
    n = math.floor((max(ends) - min(starts)) / period + 1e-6) + 1
    return min(starts) + period * np.arange(n)


def _framed(rows: list[tuple[float, float]], t_end: np.ndarray, period: float) -> np.ndarray:
    """Per frame the last reading in (t - period, t], NaN if none."""
    if not rows:
        return np.full(t_end.shape, np.nan)
    arr = np.array(sorted(rows, key=lambda r: r[0]))  # stable: equal times keep arrival order
    t, v = arr[:, 0], arr[:, 1]
    # Index of the last reading at or before each frame end (1e-6 s: millisecond stamps vs float frame times).
    idx = np.searchsorted(t, t_end + 1e-6, side="right") - 1
    ok = idx >= 0
    out = np.full(t_end.shape, np.nan)
    last_t = np.where(ok, t[np.maximum(idx, 0)], -np.inf)
    fresh = ok & (last_t > t_end - period + 1e-6)
    out[fresh] = v[idx[fresh]]
    return out


def _sample(t_src: np.ndarray, values: np.ndarray, t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Linear interpolation per column at t; NaN outside the source span or across gaps over max_gap_s."""
    out = np.full((t.size, values.shape[1]), np.nan)
    if t_src.size < 2:
        return out
    order = np.argsort(t_src, kind="stable")
    t_src, values = t_src[order], values[order]
    for c in range(values.shape[1]):
        out[:, c] = np.interp(t, t_src, values[:, c], left=np.nan, right=np.nan)
    # A frame between two samples too far apart gets no reference rather than a guess.
    right = np.clip(np.searchsorted(t_src, t), 1, t_src.size - 1)
    out[(t_src[right] - t_src[right - 1]) > max_gap_s] = np.nan
    return out


def read_truth_csv(path: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """flightsim's truth CSV (``secuav-sim --truth-csv``): per sysid (t_s, (T, 3) NED position)."""
    if not path.is_file():
        raise InputError(str(path), "--truth", str(path), "no such file")
    rows: dict[int, list[tuple[float, float, float, float]]] = defaultdict(list)
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in TRUTH_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise InputError(str(path), missing[0], None, f"missing column (need {', '.join(TRUTH_COLUMNS)})")
        for line, rec in enumerate(reader, start=2):
            try:
                sysid = int(rec["sysid"])
                t, n, e, d = (float(rec[c]) for c in ("t_s", "north_m", "east_m", "down_m"))
            except (TypeError, ValueError):
                bad = next(c for c in TRUTH_COLUMNS if not _is_number(rec.get(c)))
                raise InputError(str(path), f"line {line}: {bad}", rec.get(bad), "not a number") from None
            rows[sysid].append((t, n, e, d))
    if not rows:
        raise InputError(str(path), "rows", 0, "no truth samples")
    return {s: (np.array(r)[:, 0], np.array(r)[:, 1:4]) for s, r in rows.items()}


def _is_number(text: str | None) -> bool:
    try:
        float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def log_streams(
    logs: dict[int, VehicleLog],
    sysids: list[int],
    down_ids: dict[int, int | None],
    rate_hz: float,
    truth: dict[int, tuple[np.ndarray, np.ndarray]] | None,
) -> tuple[dict[int, VehicleStream], float]:
    """Frame the logged vehicles' readings; returns streams (t_s from the first frame) and that frame's boot time."""
    t_end = frame_times([logs[s] for s in sysids], rate_hz)
    period = 1.0 / rate_hz
    t0 = float(t_end[0])
    out = {}
    for s in sysids:
        log = logs[s]
        down = down_ids.get(s)
        if down is None:
            down = next((i for i, o in log.orientation.items() if o == ORIENTATION_DOWN and i < ANCHOR_BASE), None)
        readings = {i: _framed(rows, t_end, period) for i, rows in log.readings.items() if i != down}
        laser = _framed(log.readings.get(down, []), t_end, period) if down is not None else np.full(t_end.size, np.nan)
        if truth is not None and s in truth:
            truth_ned = _sample(truth[s][0], truth[s][1], t_end, max_gap_s=1.0)
        else:
            truth_ned = np.full((t_end.size, 3), np.nan)
        local = None
        if log.local_ned:
            arr = np.array(log.local_ned)
            local = _sample(arr[:, 0], arr[:, 1:4], t_end, max_gap_s=1.0)
        boot = t0 - period
        raw = {i: _raw(rows, float(t_end[0]) - period, float(t_end[-1]), boot) for i, rows in log.readings.items()}
        out[s] = VehicleStream(s, t_end - boot, truth_ned, readings, laser, local, boot, raw=raw)
    return out, t0 - period


def _raw(rows: list[tuple[float, float]], after: float, until: float, boot: float) -> tuple[np.ndarray, np.ndarray]:
    """The readings in (after, until] on the boot clock, in time order, as (times - boot, values)."""
    if not rows:
        return np.zeros(0), np.zeros(0)
    arr = np.array(sorted(rows, key=lambda r: r[0]))
    keep = (arr[:, 0] > after + 1e-6) & (arr[:, 0] <= until + 1e-6)
    return arr[keep, 0] - boot, arr[keep, 1]

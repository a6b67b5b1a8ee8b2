"""What every demo controller reads and writes the same way, whatever it speaks to the vehicle with.

The JSON-lines log and the rangefinder rule (the newest reading per sensor id,
left out when older than ``STALE_S`` or marked invalid by ``secuav-proxy
--secure``) are shared by the MAVSDK controllers (:mod:`demos.controllers.common`)
and the pymavlink one that flies ArduPilot
(:mod:`demos.controllers.height_hold`). Nothing here imports MAVSDK.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time
from collections.abc import Callable
from typing import IO, Any

from secuav_common.sensor_ids import QUALITY_INVALID

STALE_S = 0.5


class Log:
    """JSON lines to a file (or nowhere), flushed so a caller can follow the flight."""

    def __init__(self, out: IO[str] | None) -> None:
        self.out = out
        self.t0 = time.monotonic()

    def write(self, kind: str, **data: Any) -> None:
        if self.out is None:
            return
        stamp = {"t_s": round(time.monotonic() - self.t0, 3), "wall_s": round(time.time(), 3)}
        self.out.write(json.dumps({**stamp, "kind": kind, **data}) + "\n")
        self.out.flush()


def run_logged(fly: Callable[[argparse.Namespace, Log], None], args: argparse.Namespace) -> None:
    """Fly with ``args.log`` (a path, or None for no log) open as the JSON-lines :class:`Log`; Ctrl-C ends quietly."""
    out = open(args.log, "w", encoding="utf-8") if args.log else None  # noqa: SIM115 - closed below
    try:
        with contextlib.suppress(KeyboardInterrupt):
            fly(args, Log(out))
    finally:
        if out is not None:
            out.close()


class Ranges:
    """Newest DISTANCE_SENSOR reading per sensor id: (arrival time, metres, marked invalid)."""

    def __init__(self) -> None:
        self.by_id: dict[int, tuple[float, float, bool]] = {}

    def add(self, fields: dict[str, Any], now: float) -> None:
        cm = int(fields["current_distance"])
        if cm <= int(fields["min_distance"]) or cm >= int(fields["max_distance"]):
            return  # out of range: the sensor sees nothing
        self.by_id[int(fields["id"])] = (now, cm / 100.0, int(fields["signal_quality"]) == QUALITY_INVALID)

    def fresh(self, now: float, ids: range | set[int]) -> tuple[dict[int, float], list[int]]:
        """Readings of ``ids`` under STALE_S old and not marked invalid; and the ids marked invalid."""
        good, flagged = {}, []
        for i, (t, m, bad) in self.by_id.items():
            if i in ids and now - t <= STALE_S:
                if bad:
                    flagged.append(i)
                else:
                    good[i] = m
        return good, sorted(flagged)


def clip(value: float, limit: float) -> float:
    """``value`` limited to +-limit; an unknown value (NaN, as the secure stage sends a position it cannot
    trust) commands nothing, so the vehicle holds."""
    return max(-limit, min(limit, value)) if math.isfinite(value) else 0.0

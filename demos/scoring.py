"""Score a demo flight from ground truth (the simulator's, never the controller's belief)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from secuav_common.scenario import Scenario


@dataclass(frozen=True, slots=True)
class Window:
    """Wall-clock times (epoch s): when the hold began, and the scored part of it."""

    start_s: float
    end_s: float
    hold_s: float


def wall_distance_m(scenario: Scenario, pos_ned_m: list[float], sysid: int = 1) -> float:
    """Signed distance from the vehicle to the wall its target names (positive on the free side)."""
    vehicle = next(v for v in scenario.vehicles if v.sysid == sysid)
    wall_name = getattr(vehicle.target, "wall", None)
    wall = next(w for w in scenario.world.walls if wall_name in (None, w.name))
    p, n = np.asarray(pos_ned_m, float), np.asarray(wall.normal_ned, float)
    return float(np.dot(p - np.asarray(wall.point_ned_m, float), n / np.linalg.norm(n)))


def _rms_max(errors: list[float]) -> dict[str, float]:
    if not errors:
        return {"rms": math.nan, "max": math.nan, "samples": 0}
    a = np.abs(np.asarray(errors))
    return {"rms": round(float(np.sqrt(np.mean(a**2))), 4), "max": round(float(a.max()), 4), "samples": len(errors)}


def distance_metrics(
    scenario: Scenario,
    truth: list[tuple[float, dict[str, Any]]],
    steps: list[dict[str, Any]],
    estimates: list[tuple[float, dict[str, Any]]],
    window: Window,
    sysid: int = 1,
) -> dict[str, Any]:
    """Figures of one wall-hover flight; series are kept (relative to the hold) for the plots."""
    vehicle = next(v for v in scenario.vehicles if v.sysid == sysid)
    target_m = float(getattr(vehicle.target, "distance_m", 2.5))
    true_series = [(t, wall_distance_m(scenario, d["pos_ned_m"], sysid)) for t, d in truth]
    hit = next((t for t, d in truth if d.get("collided")), None)  # the simulator's own contact flag
    return held_distance_metrics(true_series, target_m, hit is not None, steps, estimates, window, hit)


GROUND_CONTACT_M = 0.05  # a true height above ground this low is touching it


def height_metrics(
    true_height: list[tuple[float, float]],
    target_m: float,
    steps: list[dict[str, Any]],
    estimates: list[tuple[float, dict[str, Any]]],
    window: Window,
) -> dict[str, Any]:
    """Figures of one height-hold flight (the ground as the wall): ``true_height`` is (wall time, true height above
    ground) from the simulator; "collided" is touching the ground inside the scored window (the flight begins
    and ends on it)."""
    hit = next((t for t, h in true_height if h <= GROUND_CONTACT_M and _in(window, t)), None)
    return held_distance_metrics(true_height, target_m, hit is not None, steps, estimates, window, hit)


def held_distance_metrics(
    true_series: list[tuple[float, float]],
    target_m: float,
    collided: bool,
    steps: list[dict[str, Any]],
    estimates: list[tuple[float, dict[str, Any]]],
    window: Window,
    collided_at: float | None = None,
) -> dict[str, Any]:
    """The figures of a flight that holds one distance: true (from the simulator) against the controller's;
    ``collided_at`` (the same clock as the series) is when the vehicle first touched the surface."""
    scored = [(t, d) for t, d in true_series if _in(window, t)]
    seen = [(float(s["wall_s"]), s["distance_m"]) for s in steps if s.get("distance_m") is not None]
    seen_scored = [d for t, d in seen if _in(window, t)]
    flagged_by_controller: Counter[int] = Counter(i for s in steps for i in s.get("flagged", []))
    step_us = [1e6 * float(e["step_time_s"]) for _, e in estimates if e.get("step_time_s") is not None]
    return {
        "target_distance_m": target_m,
        "distance_error_m": _rms_max([d - target_m for _, d in scored]),
        "min_distance_m": round(min((d for _, d in scored), default=math.nan), 4),
        "collided": collided,
        "collided_at_s": None if collided_at is None else round(collided_at - window.start_s, 3),  # from onset
        "seen_error_m": _rms_max([d - target_m for d in seen_scored]),
        "flagged_by_proxy": detection(estimates, window),
        "flagged_by_controller_steps": {str(k): v for k, v in sorted(flagged_by_controller.items())},
        "secure_step_time_us": {
            "median": round(float(np.median(step_us)), 1) if step_us else None,
            "p99": round(float(np.percentile(step_us, 99)), 1) if step_us else None,
        },
        "window_s": {
            "hold_to_scored": round(window.start_s - window.hold_s, 2),
            "scored": round(window.end_s - window.start_s, 2),
        },
        "series": {
            "truth": [(round(t - window.start_s, 3), round(d, 4)) for t, d in true_series],
            "seen": [(round(t - window.start_s, 3), round(d, 4)) for t, d in seen],
        },
    }


def held_summary(figures: dict[str, Any], quantity: str = "distance", contact: str = "collided") -> str:
    """The console line of a flight that holds one distance (:func:`held_distance_metrics`'s figures)."""
    err = figures["distance_error_m"]
    return (
        f"{quantity} error rms {err['rms']:.2f} m, max {err['max']:.2f} m, "
        f"min {quantity} {figures['min_distance_m']:.2f} m, {contact} {figures['collided']}"
    )


def _in(window: Window, t: float) -> bool:
    return window.start_s <= t <= window.end_s


def detection(estimates: list[tuple[float, dict[str, Any]]], window: Window) -> dict[str, float]:
    """Share of the secure stage's estimates in the window that judged each sensor id attacked."""
    counts: Counter[int] = Counter()
    n = 0
    for t, e in estimates:
        if _in(window, t):
            n += 1
            counts.update(int(i) for i in e.get("attacked", []))
    return {str(k): round(v / n, 3) for k, v in sorted(counts.items())} if n else {}


def position_metrics(
    truth: list[tuple[float, dict[str, Any]]],
    target_ne_m: tuple[float, float] | None,
    steps: list[dict[str, Any]],
    estimates: list[tuple[float, dict[str, Any]]],
    window: Window,
) -> dict[str, Any]:
    """Horizontal error of the true position from the hold target, and of the controller's fix from truth."""
    scored = [(t, d["pos_ned_m"]) for t, d in truth if _in(window, t)]
    figures: dict[str, Any] = {"collided": any(bool(d.get("collided")) for _, d in truth)}
    if target_ne_m is not None:
        figures["position_error_m"] = _rms_max(
            [math.hypot(p[0] - target_ne_m[0], p[1] - target_ne_m[1]) for _, p in scored]
        )
    if scored:
        times = np.array([t for t, _ in scored])
        fix_err = []
        for s in steps:
            t = float(s["wall_s"])
            if _in(window, t) and s.get("fix_ned_m"):
                p = scored[int(np.clip(np.searchsorted(times, t), 0, len(scored) - 1))][1]
                fix_err.append(math.hypot(s["fix_ned_m"][0] - p[0], s["fix_ned_m"][1] - p[1]))
        figures["fix_error_m"] = _rms_max(fix_err)
    figures["flagged_by_proxy"] = detection(estimates, window)
    figures["series"] = {
        "truth_ne": [
            (round(t - window.start_s, 3), round(d["pos_ned_m"][0], 4), round(d["pos_ned_m"][1], 4)) for t, d in truth
        ],
    }
    if target_ne_m is not None:
        tn, te = target_ne_m
        track = figures["series"]["truth_ne"]
        figures["series"]["error"] = [(t, round(math.hypot(n - tn, e - te), 4)) for t, n, e in track]
    return figures


Samples = list[tuple[float, dict[str, Any]]]


def range_metrics(truth_a: Samples, truth_b: Samples, keep_m: float, window: Window) -> dict[str, Any]:
    """Error of the true distance between two vehicles from the one to keep (joined on arrival time)."""
    if not truth_a or not truth_b:
        return {"range_error_m": _rms_max([]), "series": []}
    times_b = np.array([t for t, _ in truth_b])
    pairs = []
    for t, d in truth_a:
        j = int(np.clip(np.searchsorted(times_b, t), 0, len(truth_b) - 1))
        pa, pb = np.asarray(d["pos_ned_m"]), np.asarray(truth_b[j][1]["pos_ned_m"])
        pairs.append((t, float(np.linalg.norm(pa - pb))))
    return {
        "range_error_m": _rms_max([r - keep_m for t, r in pairs if _in(window, t)]),
        "series": [(round(t - window.start_s, 3), round(r, 4)) for t, r in pairs],
    }

"""Per-estimator figures of one offline trial, beyond the pooled ones of :func:`evaluation.report.summarise`.

Detection, one definition for whoever names readings: the method itself (``own_*``: the
``attacked``/``alarm`` its ``_step`` returned, null for a method that does not detect) and the shared
attribution on a secure method's output (``attribution_*``: only in its ``+attribution`` row). Ground truth
is the attack itself: a reading is attacked where the engine changed it (its offset is non-zero), whatever
the size.
- recall: attacked readings named at their step over attacked readings; precision: named readings that are
  attacked at that step over named readings; false naming: the share of steps with an estimate at which an
  honest reading is named (on clean runs: any name); alarm fraction: the share of steps with an alarm.
- detection delay: from the first attacked step to the first step at which an attacked reading is named;
  None if it never is (or nothing was attacked).
- recall by magnitude: attacked readings named, binned by |offset| in units of the sensor's noise sigma, so a
  small attack that is missed shows as missed.
- valid fraction and valid error: the steps where the estimator claims a
  trustworthy estimate (one exists and it is not degraded: ``Estimate.valid``), and the error there;
  beyond what it can correct an estimator must say so rather than be wrong.
- NEES: the mean of ``e^T P^-1 e`` over those steps (consistency: a filter
  whose covariance is honest averages the number of position dimensions).
- height RMSE: where the model estimates the height (test case 1 with the
  laser as a reading), the vertical error, which the horizontal errors hide.
Only steps after the estimators' warm-up are scored, as in ``secuav-eval``.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from evaluation.report import summarise
from evaluation.trial import TrialResult
from evaluation.variants import ATTRIBUTED

SIGMA_BINS = (0.0, 1.0, 3.0, 5.0, 10.0, float("inf"))


def _bin_label(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}"


def _finite(values: np.ndarray | None, *masks: np.ndarray) -> np.ndarray | None:
    """The finite entries of a per-step trace after the masks are applied in turn; None if there are none."""
    if values is None:
        return None
    for mask in masks:
        values = values[mask]
    finite = values[np.isfinite(values)]
    return finite if finite.size else None


DETECTION = ("recall", "precision", "false_naming", "alarm_fraction", "detection_delay_s", "recall_by_sigma")
WHO = ("own", "attribution")  # the method's own naming; the shared attribution's on its output


def detection_columns() -> list[str]:
    """Every detection column of a study row: ``own_<figure>`` and ``attribution_<figure>``."""
    return [f"{who}_{figure}" for who in WHO for figure in DETECTION]


def naming_figures(
    named: np.ndarray | None,
    alarm: np.ndarray | None,
    attacked: np.ndarray,
    has_estimate: np.ndarray,
    t: np.ndarray,
    in_sigma: np.ndarray,
) -> dict[str, Any]:
    """The one definition of detection, for whoever named (``named`` (T, p), ``alarm`` (T,) after the warm-up;
    None: nobody's claim to score, every figure None). See the module docstring."""
    if named is None or alarm is None:
        return dict.fromkeys(DETECTION)
    delay = None
    onset = np.flatnonzero(attacked.any(axis=1))
    if onset.size:
        caught = np.flatnonzero((named & attacked).any(axis=1))
        caught = caught[caught >= onset[0]]
        if caught.size:
            delay = float(t[caught[0]] - t[onset[0]])
    wrong = (named & ~attacked).any(axis=1) & has_estimate
    n_est = int(has_estimate.sum())
    by_bin: dict[str, float | None] = {}
    for lo, hi in itertools.pairwise(SIGMA_BINS):
        sel = attacked & (in_sigma > lo) & (in_sigma <= hi)
        by_bin[_bin_label(lo, hi)] = float((named & sel).sum() / sel.sum()) if sel.any() else None
    return {
        "recall": float((named & attacked).sum() / attacked.sum()) if attacked.any() else None,
        "precision": float((named & attacked).sum() / named.sum()) if named.any() else None,
        "false_naming": float(wrong.sum() / n_est) if n_est else None,
        "alarm_fraction": float(alarm.mean()) if alarm.size else None,
        "detection_delay_s": delay,
        "recall_by_sigma": by_bin,
    }


def detection_figures(trial: TrialResult, name: str, attributed: bool | None = None) -> dict[str, Any]:
    """A row's figures beyond the pooled ones; ``attributed``: the row's output is the shared attribution's
    (None: as its label says, ``+attribution``)."""
    attributed = name.endswith(ATTRIBUTED) if attributed is None else attributed
    trace = trial.traces[name]
    keep = trial.t_s > trial.score_from_s
    t = trial.t_s[keep]
    offsets = np.abs(np.nan_to_num(trial.offsets_m[keep], nan=0.0))
    attacked = offsets > 0.0
    has_estimate = np.isfinite(trace.est_xy_m[keep]).all(axis=1)
    in_sigma = offsets / trial.sigma_m
    degraded = trace.alarm if trace.degraded is None else trace.degraded
    valid = has_estimate & ~degraded[keep]  # estimates that claim to be trustworthy
    err = trace.err_m[keep]
    valid_err = err[valid & np.isfinite(err)]
    nees = _finite(trace.nees, keep, valid)
    nis = _finite(trace.nis, keep, valid)
    herr = _finite(trace.height_err_m, keep)
    own_named = None if trace.own_named is None else trace.own_named[keep]
    own_alarm = None if trace.own_alarm is None else trace.own_alarm[keep]
    own = naming_figures(own_named, own_alarm, attacked, has_estimate, t, in_sigma)
    shared = naming_figures(trace.named[keep] if attributed else None, trace.alarm[keep] if attributed else None,
                            attacked, has_estimate, t, in_sigma)  # fmt: skip
    return {
        **{f"own_{k}": v for k, v in own.items()},
        **{f"attribution_{k}": v for k, v in shared.items()},
        "height_rmse_m": None if herr is None else float(np.sqrt(np.mean(herr**2))),
        "attacked_fraction": float(attacked.any(axis=1).mean()) if t.size else 0.0,
        "valid_fraction": float(valid.mean()) if t.size else 0.0,
        "valid_rmse_m": float(np.sqrt(np.mean(valid_err**2))) if valid_err.size else None,
        "valid_max_error_m": float(valid_err.max()) if valid_err.size else None,
        "nees_mean": None if nees is None else float(np.mean(nees)),
        "nis_mean": None if nis is None else float(np.mean(nis)),
    }


def trial_rows(trial: TrialResult) -> dict[str, dict[str, Any]]:
    """Per estimator: the figures a study row stores."""
    pooled = summarise([trial])
    rows = {}
    for name, row in pooled.items():
        rng = row.get("inter_vehicle_range") or {}
        rows[name] = {
            "rmse_m": row["rmse_m"],
            "mean_error_m": row["mean_error_m"],
            "p95_error_m": row["p95_error_m"],
            "max_error_m": row["max_error_m"],
            "range_rmse_m": rng.get("rmse_m"),
            "range_max_error_m": rng.get("max_error_m"),
            "estimate_fraction": row["estimate_fraction"],
            "step_time_us_median": row["step_time_us_median"],
            "step_time_us_p99": row["step_time_us_p99"],
            "calibration": None if row.get("calibration") is None else row["calibration"][0],
            "processing": (trial.processing or {}).get(name),
            "async_window_s": trial.async_window_s,
            **detection_figures(trial, name),
        }
    return rows

"""Figures from trials: results.json fields, the summary table, and the plots (attack and error over time)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.trial import TrialResult
from evaluation.variants import ATTRIBUTED, is_secure

RECALL_SIGMAS = 5.0  # an attack counts for recall once it exceeds five noise deviations (issue 6 target)


def _nan_to_none(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _errors(e: np.ndarray) -> dict[str, float | None]:
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"rmse_m": None, "mean_error_m": None, "p95_error_m": None, "max_error_m": None}
    return {
        "rmse_m": float(np.sqrt(np.mean(e**2))),
        "mean_error_m": float(np.mean(e)),
        "p95_error_m": float(np.percentile(e, 95)),
        "max_error_m": float(np.max(e)),
    }


def _onsets(flag: np.ndarray) -> int:
    """Events: runs of consecutive flagged steps (one accusation that lasts three steps is one event)."""
    return int(np.sum(flag & ~np.concatenate([[False], flag[:-1]])))


def false_alarms(trials: list[TrialResult], name: str) -> dict[str, float | None]:
    """False alarms and false accusations of one estimator, per step, per run and per hour.

    A *false alarm* is an alarm on a step where this run's attack changed no reading (every step of a
    clean run; before the onset and in the gaps of an attacked one). A *false accusation* is a step
    on which a reading the attack left untouched is named attacked. Per step: the share of such
    steps; per run and per hour: the number of events (a run of consecutive flagged steps counts
    once), per trial and per hour of the steps they could occur on. On a recording, a reading the
    recording itself got wrong (NLOS, a gross error) is untouched by the attack, so naming it counts
    here too: the figure is what an operator would see. None where the added offsets are unknown.
    """
    alarm_events = accusation_events = alarm_steps = accusation_steps = 0
    quiet_s = all_s = 0.0
    quiet_n = all_n = 0
    for tr in trials:
        if tr.added_m is None:
            return dict.fromkeys(FALSE_ALARM_KEYS)
        trace = tr.traces[name]
        keep = tr.t_s > tr.score_from_s
        dt = float(np.median(np.diff(tr.t_s))) if tr.t_s.size > 1 else 0.0
        touched = np.abs(np.nan_to_num(tr.added_m[keep], nan=0.0)) > 0.0
        quiet = ~touched.any(axis=1)
        alarm = trace.alarm[keep] & quiet
        accused = (trace.named[keep] & ~touched).any(axis=1)
        alarm_events += _onsets(alarm)
        accusation_events += _onsets(accused)
        alarm_steps += int(alarm.sum())
        accusation_steps += int(accused.sum())
        quiet_n += int(quiet.sum())
        all_n += int(keep.sum())
        quiet_s += float(quiet.sum()) * dt
        all_s += float(keep.sum()) * dt
    runs = len(trials)
    return {
        "false_alarm_per_step": alarm_steps / quiet_n if quiet_n else None,
        "false_alarms_per_run": alarm_events / runs,
        "false_alarms_per_hour": alarm_events / (quiet_s / 3600.0) if quiet_s else None,
        "false_accusation_per_step": accusation_steps / all_n if all_n else None,
        "false_accusations_per_run": accusation_events / runs,
        "false_accusations_per_hour": accusation_events / (all_s / 3600.0) if all_s else None,
        "attack_free_hours": quiet_s / 3600.0,
    }


FALSE_ALARM_KEYS = (
    "false_alarm_per_step",
    "false_alarms_per_run",
    "false_alarms_per_hour",
    "false_accusation_per_step",
    "false_accusations_per_run",
    "false_accusations_per_hour",
    "attack_free_hours",
)


def summarise(trials: list[TrialResult]) -> dict[str, dict[str, Any]]:
    """Per estimator, pooled over trials (scored after the warm-up).

    Errors are None where no trial has ground truth (a log without ``--truth``);
    detection precision/recall are None where nothing says which readings were
    attacked. Alarms, the readings named per sensor id and step times are
    always reported.
    """
    out: dict[str, dict[str, Any]] = {}
    scored_errors = any(tr.scored_errors for tr in trials)
    scored_detection = any(tr.scored_detection for tr in trials)
    for name in trials[0].traces:
        errs, rerrs, devs, times, has_estimate = [], [], [], [], []
        hit = strong = named = named_true = alarms = steps = 0
        named_by_id = np.zeros(len(trials[0].sensor_ids))
        for tr in trials:
            trace = tr.traces[name]
            keep = tr.t_s > tr.score_from_s
            errs.append(trace.err_m[keep])
            has_estimate.append(np.isfinite(trace.est_xy_m[keep]).all(axis=1))
            if trace.range_err_m is not None:
                rerrs.append(trace.range_err_m[keep])
            if trace.local_dev_m is not None:
                devs.append(trace.local_dev_m[keep])
            times.append(trace.step_time_s)
            nm = trace.named[keep]
            named_by_id += nm.sum(axis=0)
            alarms += int(trace.alarm[keep].sum())
            steps += int(keep.sum())
            if not tr.scored_detection:
                continue
            off = np.abs(np.nan_to_num(tr.offsets_m[keep], nan=0.0))
            big = off > RECALL_SIGMAS * tr.sigma_m
            floor = 1e-9 if tr.named_floor_m is None else tr.named_floor_m
            hit += int((big & nm).sum())
            strong += int(big.sum())
            named += int(nm.sum())
            named_true += int((nm & (off > floor)).sum())
        t_us = 1e6 * np.concatenate(times)
        row: dict[str, Any] = _errors(np.concatenate(errs))
        row.update({
            "step_time_us_median": float(np.median(t_us)),
            "step_time_us_p99": float(np.percentile(t_us, 99)),
            "attack_detection_precision": _nan_to_none(named_true / named if named else float("nan")),
            "attack_detection_recall": _nan_to_none(hit / strong if strong else float("nan")),
            "alarm_fraction": alarms / steps if steps else 0.0,
            # Steps with no estimate at all: a secure start that never found a consistent subset.
            "estimate_fraction": float(np.mean(np.concatenate(has_estimate))) if steps else 0.0,
            "named_fraction_by_sensor_id": {
                str(sid): round(float(n) / steps, 4) if steps else 0.0
                for sid, n in zip(trials[0].sensor_ids, named_by_id, strict=True)
            },
        })  # fmt: skip
        row.update(false_alarms(trials, name))
        # Per trial, what --calibrate did: status, and per link the readings used, the offset and the scale.
        reports = [tr.traces[name].calibration for tr in trials]
        row["calibration"] = None if all(r is None for r in reports) else reports
        if not scored_detection:
            row["attack_detection_precision"] = row["attack_detection_recall"] = None
        if devs:
            dev = _errors(np.concatenate(devs))
            row["deviation_from_local_position_ned"] = dev
        if rerrs:
            row["inter_vehicle_range"] = _errors(np.concatenate(rerrs))
        if not scored_errors and "inter_vehicle_range" in row:
            row["inter_vehicle_range"] = None
        out[name] = row
    return out


BASELINES = ("ls", "ekf")  # undefended: the snapshot least-squares fix and the EKF, in every table


def compare_with_ls(summary: dict[str, dict[str, Any]], clean: bool) -> None:
    """Add ``rmse_vs_ls`` (RMSE over the least-squares baseline's) and, on a clean run, ``loses_to_ls_clean``
    (a secure method whose RMSE exceeds the undefended least-squares fix's) to every row."""
    base = (summary.get("ls") or {}).get("rmse_m")
    for name, row in summary.items():
        rmse = row.get("rmse_m")
        ratio = rmse / base if rmse is not None and base else None
        row["rmse_vs_ls"] = ratio
        secure = is_secure(name.removesuffix(ATTRIBUTED))  # both rows of a secure method (evaluation.variants)
        row["loses_to_ls_clean"] = bool(clean and secure and ratio is not None and ratio > 1.0) if clean else None


def _per_hour(value: float | None) -> str:
    return f"{'n/a':>15}" if value is None else f"{value:>15.0f}"


def _cell(value: float | None, width: int, scale: float = 1.0) -> str:
    return f"{'n/a':>{width}}" if value is None else f"{value * scale:>{width}.3f}"


def table(summary: dict[str, dict[str, Any]]) -> str:
    """The summary table: absolute errors and time per step."""
    two = any(row.get("inter_vehicle_range") for row in summary.values())
    w = max([10, *(len(name) + 1 for name in summary)])  # secekf+attribution and a loser's mark fit
    head = f"{'Estimator':<{w}} | {'Mean abs. error [m]':>19} | {'Max abs. error [m]':>18}"
    if two:
        head += f" | {'Range mean [m]':>14} | {'Range max [m]':>13}"
    head += f" | {'False alarms /h':>15} | {'False accus. /h':>15}"
    head += f" | {'Time per step [ms]':>18} | {'p99 [ms]':>8} | {'RMSE / LS':>10}"
    lines = [head, "-" * len(head)]
    for name, row in summary.items():
        mark = "*" if row.get("loses_to_ls_clean") else ""
        line = f"{name + mark:<{w}} | {_cell(row['mean_error_m'], 19)} | {_cell(row['max_error_m'], 18)}"
        if two:
            rng = row["inter_vehicle_range"]
            line += f" | {_cell(rng['mean_error_m'], 14)} | {_cell(rng['max_error_m'], 13)}"
        line += f" | {_per_hour(row.get('false_alarms_per_hour'))} | {_per_hour(row.get('false_accusations_per_hour'))}"
        line += f" | {row['step_time_us_median'] / 1000:>18.3f} | {row['step_time_us_p99'] / 1000:>8.3f}"
        ratio = row.get("rmse_vs_ls")
        line += f" | {'n/a':>10}" if ratio is None else f" | {ratio:>10.2f}"
        lines.append(line)
    silent = [name for name, row in summary.items() if row.get("estimate_fraction", 1.0) == 0.0]
    if silent:
        lines.append(
            f"n/a for {', '.join(silent)}: no estimate on any step (alarm throughout: more sensors attacked"
            " than the estimator tolerates, so it refuses to guess)."
        )
    if any(name.endswith(ATTRIBUTED) for name in summary):
        lines.append(
            "A secure method has two rows, as in a study's tables: `name`, its own output with the shared "
            "attribution off, and `name+attribution`, its output with SecUAV's shared attribution (results.json: "
            "output own / attributed)."
        )
    lines.append(
        "False alarms /h: alarms on steps the attack left untouched; false accus. /h: steps naming an untouched"
        " reading; events per hour (consecutive steps count once), per step and per run in results.json."
    )
    lines.append("Time per step: one step of every estimator (ReCaP: its one sensor group), median over all steps.")
    lines.append("RMSE / LS: RMSE over the undefended snapshot least-squares fix's (ls and ekf run in every table).")
    losers = [f"{n} ({row['rmse_vs_ls']:.2f}x)" for n, row in summary.items() if row.get("loses_to_ls_clean")]
    if losers:
        lines.append(f"* loses to the undefended least-squares fix on this clean run: {', '.join(losers)}.")
    lines += calibration_lines(summary)
    return "\n".join(lines)


def calibration_lines(summary: dict[str, dict[str, Any]]) -> list[str]:
    """One line per trial saying what --calibrate did (the first estimator's window; each one's in results.json)."""
    for name, row in summary.items():
        reports = row.get("calibration")
        if not reports:
            continue
        lines = []
        for i, rep in enumerate(reports):
            where = f" (trial {i})" if len(reports) > 1 else ""
            if rep is None or rep["status"] != "calibrated":
                lines.append(f"Calibration{where}: {'none' if rep is None else rep['status']}: "
                             f"{'' if rep is None else rep.get('reason')}")  # fmt: skip
                continue
            links = ", ".join(
                f"{sid}: {v['readings']} x {v['offset_m']:+.3f} m / {v['sigma_m']:.3f} m"
                for sid, v in rep["links"].items()
            )
            lines.append(f"Calibration{where} ({name}, first {rep['window_s']:g} s, {rep['steps_with_fix']} steps "
                         f"with a fix): per link, sensor id: readings used x offset / sigma told, {links}")  # fmt: skip
        return lines
    return []


def write_results(out_dir: Path, meta: dict[str, Any], summary: dict[str, dict[str, Any]]) -> Path:
    path = out_dir / "results.json"
    path.write_text(json.dumps({**meta, "estimators": summary}, indent=2, sort_keys=False) + "\n")
    return path


def plot(out_dir: Path, trial: TrialResult) -> list[Path]:
    """The attack over time, the error over time, and the trajectory with anchors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, ax = plt.subplots(figsize=(7, 3.5))
    floor = 1e-9 if trial.named_floor_m is None else RECALL_SIGMAS * trial.sigma_m
    attacked = np.flatnonzero(np.nanmax(np.abs(np.nan_to_num(trial.offsets_m)), axis=0) > floor)
    for i in attacked:
        ax.plot(trial.t_s, trial.offsets_m[:, i], label=f"sensor id {trial.sensor_ids[i]}")
    ax.set_xlabel("time [s]")
    # From a log with truth the offset is the reading minus the range the true position implies.
    ax.set_ylabel("attack offset [m]" if trial.named_floor_m is None else "reading - true range [m]")
    ax.set_title("Attack over time")
    if len(attacked):
        ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out_dir / "attack.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    n = len(trial.traces)
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.8 * n), sharex=True, squeeze=False)
    for ax, (name, tr) in zip(axes[:, 0], trial.traces.items(), strict=True):
        if trial.scored_errors or tr.local_dev_m is None:
            ax.plot(trial.t_s, tr.err_m, lw=0.8, label="position")
        else:  # a log without truth: the distance from the autopilot's own estimate instead
            ax.plot(trial.t_s, tr.local_dev_m, lw=0.8, label="vs LOCAL_POSITION_NED (not truth)")
            ax.legend(fontsize=7, loc="upper right")
        if tr.range_err_m is not None and trial.scored_errors:
            ax.plot(trial.t_s, tr.range_err_m, lw=0.8, label="inter-vehicle range")
            ax.legend(fontsize=7, loc="upper right")
        ax.set_ylabel(f"{name}\n|err| [m]", fontsize=8)
        ax.set_yscale("symlog", linthresh=0.1)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("Absolute error over time per estimator")
    fig.tight_layout()
    paths.append(out_dir / "errors.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    if trial.truth_xy_m.shape[1] == 1:  # wall hover: the distance itself over time
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.plot(trial.t_s, trial.truth_xy_m[:, 0], "k-", lw=1.5, label="truth")
        for name, tr in trial.traces.items():
            ax.plot(trial.t_s, tr.est_xy_m[:, 0], lw=0.6, alpha=0.7, label=name)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("distance to the wall [m]")
        ax.legend(fontsize=7)
        ax.set_title("Wall distance and estimates")
        fig.tight_layout()
    else:
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
        ax.scatter(trial.anchors_xy_m[:, 1], trial.anchors_xy_m[:, 0], marker="x", c="red", label="anchors")
        if trial.scored_errors:
            ax.plot(trial.truth_xy_m[:, 1], trial.truth_xy_m[:, 0], "k-", lw=1.5, label="truth")
        if trial.local_xy_m is not None:
            ax.plot(trial.local_xy_m[:, 1], trial.local_xy_m[:, 0], "k:", lw=1.0, label="LOCAL_POSITION_NED")
        for name, tr in trial.traces.items():
            ax.plot(tr.est_xy_m[:, 1], tr.est_xy_m[:, 0], lw=0.6, alpha=0.7, label=name)
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
        ax.set_aspect("equal")
        pad = 1.0
        lo, hi = trial.anchors_xy_m.min(axis=0) - pad, trial.anchors_xy_m.max(axis=0) + pad
        ax.set_xlim(lo[1], hi[1])
        ax.set_ylim(lo[0], hi[0])
        ax.legend(fontsize=7)
        ax.set_title("Trajectory and estimates (first vehicle)")
        fig.tight_layout()
    paths.append(out_dir / "trajectory.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths

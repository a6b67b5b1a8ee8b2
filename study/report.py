"""``DIR/report.md`` and ``DIR/figures/*.png`` from the stored rows of a study.

Per attack, magnitude and estimator: the mean over seeds with a 95 % bootstrap
confidence interval (``scipy.stats.bootstrap``, percentile method, fixed
random state so the same rows give the same report) of the RMSE, recall and
detection delay; the worst error over seeds; false naming on clean runs;
and a summary of error and time per step per attack and estimator. A study that sweeps
``estimator_params`` shows each grid point as its own estimator (``secekf alpha=0.001``). Rows that failed are listed,
and every group whose estimate fraction is below 1 is named: a step without an
estimate is never silently left out of an error figure.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from study.store import load, saved_study

CI_LEVEL = 0.95
RESAMPLES = 2000
GROUP = ["attack", "params", "leg", "position", "noise_scale", "recording", "estimator"]
PLACE = ["leg", "position", "noise_scale", "recording"]  # where a table's rows were measured


def mean_ci(values: Any) -> tuple[float | None, float | None, float | None, int]:
    """Mean and 95 % bootstrap CI of the finite values; (None, None, None, 0) when there are none."""
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if a.size == 0:
        return None, None, None, 0
    mean = float(a.mean())
    if a.size < 2:
        return mean, None, None, 1
    if np.all(a == a[0]):
        return mean, mean, mean, int(a.size)
    res = stats.bootstrap((a,), np.mean, confidence_level=CI_LEVEL, n_resamples=RESAMPLES, method="percentile",
                          random_state=np.random.default_rng(0))  # fmt: skip
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high), int(a.size)


def _ci(r: pd.Series, metric: str) -> str:
    return _fmt(r[metric], r[f"{metric}_lo"], r[f"{metric}_hi"])


def _missing(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _fmt(mean: float | None, lo: float | None = None, hi: float | None = None, digits: int = 3) -> str:
    if _missing(mean):
        return "n/a"
    if _missing(lo) or _missing(hi):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _magnitude_axis(frame: pd.DataFrame) -> str | None:
    """The first parameter that varies numerically across an attack's cells (the x axis of its figures)."""
    params = [json.loads(p) if p else {} for p in frame["params"].unique()]
    for key in dict.fromkeys(k for p in params for k in p):
        values = {json.dumps(p.get(key)) for p in params}
        numeric = all(isinstance(p.get(key), int | float) and not isinstance(p.get(key), bool) for p in params)
        if len(values) > 1 and numeric:
            return key
    return None


def _where(leg: str, position: str | None, noise_scale: float = 1.0, recording: str | None = None) -> str:
    if isinstance(recording, str):  # a recording fixes the path: no leg or position to name
        return f"recording {recording}"
    noise = "" if noise_scale == 1.0 else f", range noise {noise_scale:g}x what the estimators are told"
    return f"leg {leg}" + (f", position {position}" if position else "") + noise


def _row_where(r: pd.Series) -> str:
    return _where(*_place(r))


def _place(r: Any) -> tuple[Any, ...]:
    """(leg, position, noise scale, recording) of a row or a group key, with missing values as None."""
    values = [r[c] for c in PLACE] if isinstance(r, pd.Series) else list(r)
    return tuple(None if _missing(v) else v for v in values)


def _mean_or_none(values: pd.Series, *, median: bool = False) -> float | None:
    values = values.dropna()
    if not len(values):
        return None
    return float(values.median() if median else values.mean())


def summarise(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per (attack, params, leg, position, noise scale, recording, estimator) of the successful rows."""
    out = []
    for key, g in frame.groupby(GROUP, dropna=False, sort=False):
        row = dict(zip(GROUP, key, strict=True))
        row["n"] = len(g)
        for metric in ("rmse_m", *DETECTION_SCORED, "valid_rmse_m", "nees_mean", "nis_mean"):
            m, lo, hi, n = mean_ci(g[metric].tolist())
            row.update({metric: m, f"{metric}_lo": lo, f"{metric}_hi": hi, f"{metric}_n": n})
        worst = g["max_error_m"].dropna()
        row["worst_error_m"] = float(worst.max()) if len(worst) else None
        row["estimate_fraction"] = _mean_or_none(g["estimate_fraction"])
        row["valid_fraction"] = _mean_or_none(g["valid_fraction"])
        for who in ("own", "attribution"):
            row[f"{who}_alarm_fraction"] = _mean_or_none(g[f"{who}_alarm_fraction"])
        row["step_time_us_median"] = _mean_or_none(g["step_time_us_median"], median=True)
        row["collided"] = _mean_or_none(g["collided"].astype(float))
        out.append(row)
    return pd.DataFrame(out)


# The detection figures (study.metrics, one definition) with a CI in the tables: the method's own naming and the
# shared attribution's, under the results' own column names.
DETECTION_SCORED = tuple(f"{who}_{figure}" for who in ("own", "attribution")
                         for figure in ("recall", "precision", "false_naming", "detection_delay_s"))  # fmt: skip
BASELINE = "ls"  # the undefended snapshot least-squares fix every offline table is compared with


def secure_names(frame: pd.DataFrame) -> dict[str, bool]:
    """Per estimator label: whether the method it runs is a secure one (a plugin that cannot be loaded: False)."""
    import estimators

    names = frame["estimator_name"] if "estimator_name" in frame else frame["estimator"]
    out = {}
    for label, name in zip(frame["estimator"], names, strict=True):
        try:
            out[label] = bool(estimators.registry.get(name if isinstance(name, str) else label).secure)
        except (ValueError, ImportError):
            out[label] = False
    return out


def _vs_ls(summary: pd.DataFrame, ls_of: dict[str, str]) -> pd.Series:
    """Each group's mean RMSE over the least-squares baseline's in the same place and at the same grid point of
    ``estimator_params`` (``ls_of``: label -> that baseline's label); NaN where it has none."""
    where = ["attack", "params", *PLACE]

    def place(r: pd.Series) -> tuple[Any, ...]:
        return tuple(None if _missing(r[c]) else r[c] for c in where)  # NaN != NaN: a missing position or params

    ls = {(r["estimator"], *place(r)): r["rmse_m"] for _, r in summary.iterrows()}
    ratio = []
    for _, r in summary.iterrows():
        base = ls.get((ls_of.get(r["estimator"], BASELINE), *place(r)))
        ok = base is not None and not _missing(base) and base > 0 and not _missing(r["rmse_m"])
        ratio.append(float(r["rmse_m"]) / float(base) if ok else float("nan"))
    return pd.Series(ratio, index=summary.index)


def _ratio_cell(ratio: float, worse: bool) -> str:
    if _missing(ratio):
        return "n/a"
    return f"{ratio:.2f}" + (" **worse than LS**" if worse else "")


def _attack_section(name: str, s: pd.DataFrame, closed_loop: bool) -> list[str]:
    axis = _magnitude_axis(s)
    lines = [f"### {name}", ""]
    head = ["magnitude" if axis is None else axis, "estimator", "n", "RMSE [m] mean [95% CI]", "worst [m]"]
    if not closed_loop:
        head.append("RMSE / LS")
    offline = [*(f"{c} (detected/n)" if c.endswith("delay_s") else c for c in DETECTION_SCORED),
               "claimed valid", "RMSE when claimed valid [m]"]  # fmt: skip
    head += ["collided"] if closed_loop else offline
    for place, block in s.groupby(PLACE, dropna=False, sort=False):
        lines += [f"{_where(*_place(place))}:", ""]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        block = block.assign(_x=[_x_value(p, axis) for p in block["params"]]).sort_values(["_x", "estimator"])
        for _, r in block.iterrows():
            x = r["params"] if axis is None else r["_x"]
            cells = [str(x), r["estimator"], str(r["n"]), _fmt(r["rmse_m"], r["rmse_m_lo"], r["rmse_m_hi"]),
                     _fmt(r["worst_error_m"])]  # fmt: skip
            if not closed_loop:
                cells.append(_ratio_cell(r["vs_ls"], False))
            if closed_loop:
                cells.append("n/a" if _missing(r["collided"]) else f"{r['collided']:.0%}")
            else:
                for c in DETECTION_SCORED:
                    if c.endswith("delay_s"):
                        cells.append(f"{_fmt(r[c], r[f'{c}_lo'], r[f'{c}_hi'], 2)} ({r[f'{c}_n']}/{r['n']})")
                    else:
                        cells.append(_fmt(r[c], r[f"{c}_lo"], r[f"{c}_hi"]))
                cells += [
                    "n/a" if _missing(r["valid_fraction"]) else f"{r['valid_fraction']:.0%}",
                    _fmt(r["valid_rmse_m"], r["valid_rmse_m_lo"], r["valid_rmse_m_hi"]),
                ]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def _claimed(g: pd.DataFrame, figure: str) -> str:
    """A detection figure of these rows (study.metrics, one definition), the attribution's in ``+attribution``
    rows and the method's own otherwise, averaged over the recordings."""
    # The label may carry the study's grid point after a space (labelled): "secekf+attribution calibration_s=20.0".
    who = "attribution" if str(g["estimator"].iloc[0]).split(" ", 1)[0].endswith("+attribution") else "own"
    return _fmt(_mean_or_none(g[f"{who}_{figure}"].astype(float)))


def _across(summary: pd.DataFrame, recordings: list[str], secure: dict[str, bool]) -> list[str]:
    """Per attack, magnitude and estimator: the recordings' own means averaged with each recording weighted
    the same (a long recording does not outvote a short one), the worst error of any, and the spread of the
    per-recording RMSE / LS."""
    lines = [f"## Across {len(recordings)} recordings: {', '.join(recordings)}", "",
             "Each recording weighted the same: the mean over recordings of each recording's mean over seeds. "
             "RMSE / LS: the mean of the per-recording ratios, with their lowest and highest; recall (attacked "
             "runs only), false naming and alarms per step (the share of scored steps with an alarm) likewise "
             "averaged over the recordings that have them. \"recordings\" counts those with rows.",
             "",
             "| attack | magnitude | estimator | recordings | RMSE [m] | worst [m] | RMSE / LS mean (min-max) "
             "| recall | false naming | alarms / step |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    s = summary[summary["recording"].notna()]
    for (attack, params, est), g in s.groupby(["attack", "params", "estimator"], dropna=False, sort=False):
        ratios = g["vs_ls"].dropna()
        ratio = "n/a" if not len(ratios) else (
            f"{ratios.mean():.2f} ({ratios.min():.2f}-{ratios.max():.2f})"
            + (" **worse than LS**" if attack == "none" and secure.get(est, False) and ratios.mean() > 1.0 else "")
        )  # fmt: skip
        cells = [str(attack), "" if _missing(params) else str(params), str(est),
                 f"{g['recording'].nunique()}/{len(recordings)}", _fmt(_mean_or_none(g["rmse_m"])),
                 _fmt(g["worst_error_m"].astype(float).max(skipna=True)), ratio,
                 "-" if attack == "none" else _claimed(g, "recall"), _claimed(g, "false_naming"),
                 _claimed(g, "alarm_fraction")]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def _x_value(params: str | None, axis: str | None) -> float:
    if axis is None or not params:
        return 0.0
    value = json.loads(params).get(axis)
    return float(value) if isinstance(value, int | float) else 0.0


def _table51(frame: pd.DataFrame, closed_loop: bool = False) -> list[str]:
    lines = ["## Summary: error and time per step, per attack and estimator", "",
             "Pooled over magnitudes, positions, legs, noise scales, recordings and seeds (successful rows only)"
             + ("." if closed_loop else "; RMSE / LS: the mean RMSE over the undefended least-squares fix's."), "",
             "| attack | estimator | mean abs. error [m] | max abs. error [m] | time per step [ms] |"
             + ("" if closed_loop else " RMSE / LS |"),
             "|---|---|---|---|---|" + ("" if closed_loop else "---|")]  # fmt: skip
    ls_rmse = frame.groupby(["attack", "estimator"], sort=False)["rmse_m"].mean()
    ls_of = dict(zip(frame["estimator"], frame["ls_label"], strict=True)) if "ls_label" in frame else {}
    secure = secure_names(frame)
    for (attack, est), g in frame.groupby(["attack", "estimator"], sort=False):
        mean = g["mean_error_m"].mean() if g["mean_error_m"].notna().any() else g["rmse_m"].mean()
        worst = g["max_error_m"].max()
        step = g["step_time_us_median"].median()
        step_text = "n/a" if pd.isna(step) else f"{step / 1000:.3f}"
        line = f"| {attack} | {est} | {_fmt(mean)} | {_fmt(worst)} | {step_text} |"
        if not closed_loop:
            base = ls_rmse.get((attack, ls_of.get(est, BASELINE)))
            rmse = g["rmse_m"].mean()
            ratio = float(rmse / base) if base is not None and not _missing(base) and base > 0 else float("nan")
            worse = attack == "none" and secure.get(est, False) and not _missing(ratio) and ratio > 1.0
            line += f" {_ratio_cell(ratio, worse)} |"
        lines.append(line)
    return [*lines, ""]


def _figures(out: Path, summary: pd.DataFrame) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for attack, s in summary.groupby("attack", sort=False):
        axis = _magnitude_axis(s)
        if axis is None:
            continue
        places = list(s.groupby(PLACE, dropna=False, sort=False))
        width = max(6.5, 4.6 * len(places))
        fig, axes = plt.subplots(2, len(places), figsize=(width, 7), squeeze=False, sharex=True)
        for col, (place, block) in enumerate(places):
            for est, e in block.groupby("estimator", sort=False):
                e = e.assign(_x=[_x_value(p, axis) for p in e["params"]]).sort_values("_x")
                # The delay of the row's own output: the attribution's in a +attribution row, else the method's.
                who = "attribution" if str(est).endswith("+attribution") else "own"
                delay = f"{who}_detection_delay_s"
                for row, metric in enumerate(("rmse_m", delay)):
                    ax = axes[row, col]
                    y = e[metric].astype(float)
                    line = ax.plot(e["_x"], y, marker="o", ms=3, lw=1.2, label=est)[0]
                    lo, hi = e[f"{metric}_lo"].astype(float), e[f"{metric}_hi"].astype(float)
                    ax.fill_between(e["_x"], lo, hi, color=line.get_color(), alpha=0.15, lw=0)
            axes[0, col].set_title(_where(*_place(place)), fontsize=9)
            axes[0, col].set_ylabel("RMSE [m] (mean, 95% CI)")
            axes[1, col].set_ylabel("detection delay [s]")
            axes[1, col].set_xlabel(axis)
            xs = [_x_value(p, axis) for p in s["params"]]
            for ax in axes[:, col]:
                ax.grid(True, alpha=0.3)
                if min(xs) > 0 and max(xs) / min(xs) >= 10:
                    ax.set_xscale("log")
        for ax in axes[0, :]:
            ax.set_yscale("symlog", linthresh=0.05)
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"{attack}: error and detection delay vs {axis}")
        fig.tight_layout()
        path = fig_dir / f"{attack}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def _label(name: str, params: str | None) -> str:
    if not isinstance(params, str) or not params:
        return name
    return name + " " + " ".join(f"{k}={v}" for k, v in json.loads(params).items())


def readings(rows: pd.DataFrame) -> list[str]:
    """Per recording in ``rows`` (study file order as given), how its readings were taken, from the rows'
    ``processing`` and ``async_window_s``: ``lias-mid asynchronous (window 0.1 s; sequential updates: ekf; aligned:
    ls, secekf)`` or ``lias-mid framed``. Empty for flights (framed by construction, docs/recorded-ranges.md)."""
    if "recording" not in rows or "processing" not in rows:
        return []
    out = []
    for name, g in rows[rows["recording"].notna()].groupby("recording", sort=False):
        modes = set(g["processing"].dropna())
        if not modes or modes == {"synchronous"}:  # no processing column: rows from before it, all framed
            out.append(f"{name} framed")
            continue
        windows = ", ".join(f"{w:g} s" for w in sorted(set(g["async_window_s"].dropna())))
        said = {"sequential": "sequential updates", "aligned": "aligned", "synchronous": "framed"}
        kinds = [f"{said[kind]}: {', '.join(sorted(set(g.loc[g['processing'] == kind, 'estimator_name'])))}"
                 for kind in said if kind in modes]  # fmt: skip
        word = "asynchronous" if "synchronous" not in modes else "asynchronous and framed rows"
        out.append(f"{name} {word} (window {windows}; {'; '.join(kinds)})")
    return out


def labelled(frame: pd.DataFrame) -> pd.DataFrame:
    """The estimator column with its grid point of ``estimator_params`` (``secekf alpha=0.001``), if any; and
    ``ls_label``, the least-squares baseline's label at the same grid point (what the row is compared with)."""
    if "estimator_params" not in frame or frame["estimator_params"].isna().all():
        return frame.assign(ls_label=BASELINE)
    params = frame["estimator_params"]
    return frame.assign(estimator=[_label(n, p) for n, p in zip(frame["estimator"], params, strict=True)],
                        ls_label=[_label(BASELINE, p) for p in params])  # fmt: skip


def write_report(out: Path) -> Path:
    """(Re)write ``report.md`` and the figures from what ``results.parquet`` holds now."""
    frame = labelled(load(out))
    study = saved_study(out) or {}
    listed = [r.get("name") for r in study.get("recordings") or [] if isinstance(r, dict)]
    recordings = [r for r in dict.fromkeys([*listed, *frame["recording"].dropna()]) if r in set(frame["recording"])]
    rank = {r: i for i, r in enumerate(recordings)}
    taken = readings(frame[frame["status"] == "ok"].sort_values("recording", key=lambda c: c.map(rank),
                                                                  kind="stable"))  # fmt: skip
    if len(recordings) < 2:  # one recording (or flights): its tables read as before, with no recording to name
        frame = frame.assign(recording=None)
    else:  # tables in the study file's order of recordings, not the order their cells finished in
        frame = frame.sort_values("recording", key=lambda c: c.map(rank), kind="stable").reset_index(drop=True)
    ok = frame[frame["status"] == "ok"]
    failed = frame[frame["status"] != "ok"]
    closed_loop = study.get("mode") == "closed-loop"
    lines = [f"# Study {study.get('name', out.name)}", ""]
    lines += [
        f"- mode: {study.get('mode', 'n/a')}; scenario: {study.get('scenario', 'n/a')}; "
        f"duration {study.get('duration_s') or 'the scenario default'} s",
        f"- rows: {len(frame)} ({len(ok)} ok, {len(failed)} failed) over {frame['cell'].nunique()} cells; "
        f"workers: {', '.join(sorted(str(w) for w in ok['worker'].dropna().unique())) or 'n/a'}",
        f"- means over seeds with {CI_LEVEL:.0%} bootstrap confidence intervals ({RESAMPLES} resamples)",
        "- a secure method has two rows: `name`, its own output, and `name+attribution`, its output with SecUAV's "
        "shared attribution; detection: `own_*` the method's own naming, `attribution_*` the attribution's, one "
        "definition (docs/bench.md, \"Detection\")",
        *([f"- recorded readings (docs/recorded-ranges.md): {'; '.join(taken)}"] if taken else []),
        "",
    ]
    if len(failed):
        lines += [f"## Failed ({failed['cell'].nunique()} cells)", ""]
        for _, r in failed.drop_duplicates("cell").head(20).iterrows():
            lines.append(f"- cell {r['cell']} ({r['attack']} {r['params']}, seed {r['seed']}): {r['error']}")
        lines.append("")
    if not len(ok):
        lines.append("No successful rows yet.")
    else:
        summary = summarise(ok)
        ls_of = dict(zip(ok["estimator"], ok["ls_label"], strict=True))
        summary = summary.assign(vs_ls=_vs_ls(summary, ls_of))
        secure = secure_names(ok)
        partial = summary[summary["estimate_fraction"].notna() & (summary["estimate_fraction"] < 1.0)]
        if len(partial):
            lines += ["## Where estimators gave no estimate on some steps", "",
                      "Errors count only steps with an estimate; these groups lacked one at times:", ""]  # fmt: skip
            for _, r in partial.iterrows():
                lines.append(f"- {r['estimator']} on {r['attack']} {r['params'] or ''} "
                             f"({_row_where(r)}): "
                             f"estimate on {r['estimate_fraction']:.1%} of steps")  # fmt: skip
            lines.append("")
        clean = summary[summary["attack"] == "none"]
        if len(clean) and not closed_loop:
            lines += ["## Clean runs: false alarms", "",
                      "NEES: mean of e' P^-1 e over the steps claimed valid; an estimator whose covariance is "
                      "honest averages the number of position dimensions (2; 1 for a wall distance). "
                      "NIS: the output filter's normalised innovation squared per degree of freedom over the "
                      "same steps (1 when its covariance and noise model are honest; none for snapshot "
                      "estimators).", "",
                      "RMSE / LS: the mean RMSE over the undefended snapshot least-squares fix's in the same "
                      "place; a secure method above 1 loses to it on clean data and is marked.", "",
                      "| estimator | where | n | own_false_naming [95% CI] | attribution_false_naming [95% CI] "
                      "| RMSE [m] [95% CI] | RMSE / LS | NEES [95% CI] | NIS / dof [95% CI] |",
                      "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
            losers = []
            for _, r in clean.iterrows():
                where = _row_where(r)
                worse = secure.get(r["estimator"], False) and not _missing(r["vs_ls"]) and r["vs_ls"] > 1.0
                if worse:
                    losers.append(f"{r['estimator']} ({where}: {r['vs_ls']:.2f}x)")
                lines.append(f"| {r['estimator']} | {where} | {r['n']} | "
                             f"{_ci(r, 'own_false_naming')} | {_ci(r, 'attribution_false_naming')} | "
                             f"{_fmt(r['rmse_m'], r['rmse_m_lo'], r['rmse_m_hi'])} | "
                             f"{_ratio_cell(r['vs_ls'], worse)} | "
                             f"{_fmt(r['nees_mean'], r['nees_mean_lo'], r['nees_mean_hi'], 2)} | "
                             f"{_fmt(r['nis_mean'], r['nis_mean_lo'], r['nis_mean_hi'], 2)} |")  # fmt: skip
            lines.append("")
            if losers:
                lines += ["Secure methods that lose to the undefended least-squares fix on clean data: "
                          + "; ".join(losers) + ".", ""]  # fmt: skip
        lines += ["## Per attack and magnitude", ""]
        attacked = summary if closed_loop else summary[summary["attack"] != "none"]
        for attack, s in attacked.groupby("attack", sort=False):
            lines += _attack_section(str(attack), s, closed_loop)
        if len(recordings) > 1:
            lines += _across(summary, recordings, secure)
        lines += _table51(ok, closed_loop)
        figures = _figures(out, summary)
        if figures:
            lines += ["## Figures", ""] + [f"![{p.stem}](figures/{p.name})" for p in figures] + [""]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path

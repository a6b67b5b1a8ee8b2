"""Run one cell where a Dask worker (or a plain loop) calls it: rows back, nothing written.

A cell that raises still returns rows, one per estimator, with ``status`` =
``error`` and the error text, so the study records it and goes on.
"""

from __future__ import annotations

import subprocess
import time
import traceback
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from study import provenance
from study.spec import Cell, Variant, with_attribution
from study.store import as_json


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):  # not inside a Dask worker: the plain loop of the benchmark
        return "local"


def base_row(cell: Cell, variant: Variant | str) -> dict[str, Any]:
    v = Variant(variant, variant, {}) if isinstance(variant, str) else variant
    estimator = v.label
    return {
        "study": cell.study,
        "cell": cell.key,
        "scenario": cell.scenario.name,
        "mode": cell.mode,
        "leg": cell.leg,
        "position": as_json(None if cell.position is None else list(cell.position)),
        "noise_scale": cell.noise_scale,
        "recording": cell.recording_name,
        "attack": cell.attack,
        "attack_hash": None if cell.profile is None else cell.profile.content_hash()[:16],
        "params": as_json(cell.params),
        "seed": cell.seed,
        "estimator": estimator,
        "estimator_params": as_json(cell.estimator_params) if cell.estimator_params else None,
        "estimator_name": v.name,
        "output": v.output,
    }


def as_variants(given: list[Variant] | list[str], mode: str = "offline") -> list[Variant]:
    """Variants as given; a plain name stands for its rows as a study lists them (a secure method's two)."""
    out: list[Variant] = []
    for v in given:
        out += with_attribution(v, v, {}, mode) if isinstance(v, str) else [v]
    return out


def run_offline(cell: Cell, variants: list[Variant] | list[str]) -> dict[str, dict[str, Any]]:
    """Every estimator variant (or plain name) on the same attacked streams of one seeded headless flight,
    or of the cell's recording (recorded ranges: the seed seeds the attack engine only; each reading at its own
    time unless the recording is framed, ``Cell.asynchronous``, as ``secuav-eval --ranges`` takes it)."""
    from evaluation.trial import evaluate, run_trial
    from study.metrics import trial_rows

    variants = as_variants(variants)
    labels = [v.label for v in variants]
    own = {v.label: (v.name, v.build_params()) for v in variants}
    if cell.recording is not None:
        from attack_profiles import Engine

        engine = None if cell.profile is None else Engine(cell.profile, seed=cell.seed, scenario=cell.scenario)
        trial = evaluate(
            cell.scenario, cell.recording.streams, engine, labels, from_log=True, params=cell.estimator_params,
            dims=cell.dims, variants=own, asynchronous=cell.asynchronous, window_s=cell.window_s,
        )  # fmt: skip
        return trial_rows(trial)
    trial = run_trial(cell.scenario, cell.profile, labels, cell.seed, cell.duration_s, cell.leg,
                      cell.estimator_params, cell.dims, variants=own, noise_scale=cell.noise_scale)  # fmt: skip
    return trial_rows(trial)


def _provenance(cell: Cell, v: Variant) -> dict[str, Any]:
    try:
        return provenance.row_columns(v.name, cell.profile)
    except Exception as exc:  # a plugin gone from this worker: the row says so rather than losing the cell
        return {"code_key": None, "estimator_code": f"unavailable: {type(exc).__name__}: {exc}"}


def _refused(cell: Cell, variants: list[Variant], why: str, expected: dict[str, Any]) -> list[dict[str, Any]]:
    """Error rows, one line of why, stamped with the client's code_key so that only ``--retry-failed`` redoes
    them (like any failed cell)."""
    rows = []
    for v in variants:
        row = base_row(cell, v)
        row.update(status="error", error=why, worker=_worker_address(), started_at=datetime.now(UTC), wall_s=0.0,
                   code_key=provenance.key_of(v.name, expected))  # fmt: skip
        rows.append(row)
    return rows


def _checked(cell: Cell, variants: list[Variant], expected: dict[str, Any], fresh: bool) -> list[dict[str, Any]] | None:
    """None when this process's loaded code is the client's; else the cell's rows computed by a child process that
    loaded the code on disk (``fresh``, :mod:`study.fresh`), or refused with one line when that code is not the
    client's either."""
    names = [v.name for v in variants]
    diffs = provenance.differences(provenance.identity(names, cell.profile), expected)
    if not diffs:
        return None
    if not fresh:  # already the new process: the code on this machine's disk is not the client's
        why = f"code differs from the client's on this machine: {'; '.join(diffs)}"
        return _refused(cell, variants, f"{why}; install the client's versions here (docs/bench.md)", expected)
    from study import fresh as fresh_process

    try:
        rows = fresh_process.run(cell, variants, expected)
    except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
        return _refused(cell, variants, f"{exc}", expected)
    where = _worker_address()
    for row in rows:
        row.update(worker=where, fresh_process=True)  # fresh_process: counted by the runner, not stored
    return rows


def run_cell(
    cell: Cell, variants: list[Variant] | list[str], expected: dict[str, Any] | None = None, *, fresh: bool = True
) -> list[dict[str, Any]]:
    """The rows of one cell for the estimator ``variants`` (status ok, or error with its text).

    ``expected``: the client's :func:`study.provenance.identity` for these variants; when this process loaded other
    code, the cell runs in a new process instead (see :func:`_checked` and :mod:`study.fresh`)."""
    variants = as_variants(variants, cell.mode)
    if expected is not None:
        checked = _checked(cell, variants, expected, fresh)
        if checked is not None:
            return checked
    started = datetime.now(UTC)
    t0 = time.perf_counter()
    worker = _worker_address()
    try:
        if cell.mode == "offline":
            figures = run_offline(cell, variants)
        else:
            from study.closed_loop import run_closed_loop

            figures = run_closed_loop(cell, [v.name for v in variants])
        failure = None
    except Exception as exc:  # recorded in the results; the study goes on with the other cells
        figures = {}
        where = traceback.extract_tb(exc.__traceback__)[-1]
        failure = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno} in {where.name})"
    wall_s = time.perf_counter() - t0
    rows = []
    for v in variants:
        row = base_row(cell, v)
        row.update(_provenance(cell, v))
        per = figures.get(v.label, figures.get(v.name) if cell.mode != "offline" else None)
        if per is None:
            row.update(status="error", error=failure or "no result for this estimator")
        else:
            err = per.pop("error", None)
            row.update(per, status="error" if err else "ok", error=err)
        row.update(worker=worker, started_at=started, wall_s=wall_s)
        for key in ("own_recall_by_sigma", "attribution_recall_by_sigma", "flagged", "calibration"):
            if isinstance(row.get(key), dict):
                row[key] = as_json(row[key])
        rows.append(row)
    return rows

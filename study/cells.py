"""Run one cell where a Dask worker (or a plain loop) calls it: rows back, nothing written.

A cell that raises still returns rows, one per estimator, with ``status`` =
``error`` and the error text, so the study records it and goes on.
"""

from __future__ import annotations

import time
import traceback
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from study.spec import Cell
from study.store import as_json


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):  # not inside a Dask worker: the plain loop of the benchmark
        return "local"


def base_row(cell: Cell, estimator: str) -> dict[str, Any]:
    return {
        "study": cell.study,
        "cell": cell.key,
        "scenario": cell.scenario.name,
        "mode": cell.mode,
        "leg": cell.leg,
        "position": as_json(None if cell.position is None else list(cell.position)),
        "attack": cell.attack,
        "attack_hash": None if cell.profile is None else cell.profile.content_hash()[:16],
        "params": as_json(cell.params),
        "seed": cell.seed,
        "estimator": estimator,
        "estimator_params": as_json(cell.estimator_params) if cell.estimator_params else None,
    }


def run_offline(cell: Cell, names: list[str]) -> dict[str, dict[str, Any]]:
    """Every estimator on the same attacked streams of one seeded headless flight."""
    from evaluation.trial import evaluate, run_trial
    from study.metrics import trial_rows

    if cell.recording is not None:  # recorded ranges: the seed seeds the attack engine only
        from attack_profiles import Engine

        engine = None if cell.profile is None else Engine(cell.profile, seed=cell.seed, scenario=cell.scenario)
        trial = evaluate(
            cell.scenario, cell.recording.streams, engine, names, from_log=True, params=cell.estimator_params,
            dims=cell.dims,
        )  # fmt: skip
        return trial_rows(trial)
    trial = run_trial(
        cell.scenario, cell.profile, names, cell.seed, cell.duration_s, cell.leg, cell.estimator_params, cell.dims
    )
    return trial_rows(trial)


def run_cell(cell: Cell, names: list[str]) -> list[dict[str, Any]]:
    """The rows of one cell for the estimators ``names`` (status ok, or error with its text)."""
    started = datetime.now(UTC)
    t0 = time.perf_counter()
    worker = _worker_address()
    try:
        if cell.mode == "offline":
            figures = run_offline(cell, names)
        else:
            from study.closed_loop import run_closed_loop

            figures = run_closed_loop(cell, names)
        failure = None
    except Exception as exc:  # recorded in the results; the study goes on with the other cells
        figures = {}
        where = traceback.extract_tb(exc.__traceback__)[-1]
        failure = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno} in {where.name})"
    wall_s = time.perf_counter() - t0
    rows = []
    for name in names:
        row = base_row(cell, name)
        per = figures.get(name)
        if per is None:
            row.update(status="error", error=failure or "no result for this estimator")
        else:
            err = per.pop("error", None)
            row.update(per, status="error" if err else "ok", error=err)
        row.update(worker=worker, started_at=started, wall_s=wall_s)
        for key in ("recall_by_sigma", "flagged"):
            if isinstance(row.get(key), dict):
                row[key] = as_json(row[key])
        rows.append(row)
    return rows

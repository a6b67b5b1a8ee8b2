"""Run the cells of a study on Dask and store their rows as they finish.

The client submits one task per cell that still lacks rows, then writes each
batch of finished cells to ``DIR/results.parquet`` at once (see
:mod:`study.store`); workers only compute and return rows, so they need no
shared disk. A cell whose task raised, or whose worker died, is recorded with
its error and the rest go on. Ctrl-C or SIGTERM loses only the cells that were
running; a re-run with the same ``DIR`` picks up from there.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tqdm import tqdm

from study import provenance
from study.cells import as_variants, base_row, run_cell
from study.spec import Cell, Variant
from study.store import Writer, load


@dataclass
class Summary:
    cells: int
    ran: int = 0
    skipped: int = 0
    failed: int = 0
    interrupted: bool = False
    changed: int = 0  # cells re-run because the code of one of their rows changed
    fresh: int = 0  # cells a worker ran in a new process because it had loaded other code than the client's

    def as_dict(self, out: Path) -> dict[str, Any]:
        return {"cells": self.cells, "ran": self.ran, "skipped": self.skipped, "failed": self.failed,
                "changed": self.changed, "fresh": self.fresh, "out": str(out)}  # fmt: skip


def _expected_key(cell: Cell, v: Variant, cache: dict[tuple[str, str], str]) -> str:
    k = (v.name, "" if cell.profile is None else cell.profile.content_hash())
    if k not in cache:
        cache[k] = provenance.code_key(v.name, cell.profile)
    return cache[k]


def plan(
    cells: list[Cell], variants: list[Variant], done: dict[tuple[str, str], str | None]
) -> tuple[list[tuple[Cell, list[Variant]]], int]:
    """Per cell, the estimator variants it still lacks or whose code changed since their row was computed
    (cells with none left are skipped); and how many cells run again only because code changed."""
    out = []
    changed = 0
    cache: dict[tuple[str, str], str] = {}
    for cell in cells:
        missing, stale = [], False
        for v in variants:
            if (cell.key, v.label) not in done:
                missing.append(v)
            elif done[(cell.key, v.label)] != _expected_key(cell, v, cache):
                missing.append(v)
                stale = True
        if missing:
            out.append((cell, missing))
            changed += stale
    return out, changed


def cluster_ports(base: int, workers: int) -> int:
    """How many loopback ports ``--ports BASE`` takes from BASE: the scheduler and its HTTP endpoint, then per
    worker its nanny, the worker and the worker's HTTP endpoint."""
    return 2 + 3 * workers


def _pinned_cluster(workers: int, base: int) -> Any:
    """The embedded cluster on ports BASE.. (see :func:`cluster_ports`), every one on 127.0.0.1."""
    from distributed import Nanny, Scheduler, SpecCluster

    host = "127.0.0.1"
    spec = {
        i: {"cls": Nanny, "options": {
            "host": host, "port": base + 2 + 3 * i, "worker_port": base + 3 + 3 * i,
            "dashboard_address": f"{host}:{base + 4 + 3 * i}", "nthreads": 1, "name": i,
            "silence_logs": logging.ERROR,
        }}
        for i in range(workers)
    }  # fmt: skip
    sched = {"cls": Scheduler, "options": {"host": host, "port": base, "dashboard_address": f"{host}:{base + 1}"}}
    return SpecCluster(workers=spec, scheduler=sched, silence_logs=logging.ERROR, name="secuav-study")


@contextlib.contextmanager
def dask_client(workers: int | None, scheduler: str | None, base_port: int | None = None) -> Iterator[Any]:
    """An embedded LocalCluster (one single-threaded process per worker; on ports ``base_port``.. when given), or a
    client of a running scheduler."""
    import dask
    from distributed import Client, LocalCluster

    # Let workers queue cells ahead, so none waits a scheduler round trip between two cells.
    dask.config.set({"distributed.scheduler.worker-saturation": float("inf")})
    if scheduler is not None:
        with Client(scheduler, timeout="15s") as client:
            yield client
        return
    if base_port is not None:
        with _pinned_cluster(workers or os.cpu_count() or 1, base_port) as cluster, Client(cluster) as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _failed_rows(cell: Cell, variants: list[Variant], error: BaseException) -> list[dict[str, Any]]:
    rows = []
    for v in variants:
        row = base_row(cell, v)
        row.update(status="error", error=f"{type(error).__name__}: {error}", worker=None,
                   started_at=datetime.now(UTC), wall_s=None)  # fmt: skip
        rows.append(row)
    return rows


def failed_cells(out: Path) -> int:
    frame = load(out)
    return int(frame.loc[frame["status"] != "ok", "cell"].nunique()) if len(frame) else 0


def run(
    cells: list[Cell],
    variants: list[Variant] | list[str],
    out: Path,
    client: Any,
    done: dict[tuple[str, str], str | None],
    *,
    label: str = "cells",
    progress: bool = True,
) -> Summary:
    """Submit what is not done, write rows as cells finish; returns the counts of this run."""
    from distributed import as_completed

    variants = as_variants(variants, cells[0].mode if cells else "offline")
    todo, changed = plan(cells, variants, done)
    summary = Summary(cells=len(cells), skipped=len(cells) - len(todo), changed=changed)
    if changed:
        print(f"secuav-study: {changed} cells re-run because their code changed", file=sys.stderr, flush=True)
    if not todo:
        return summary
    writer = Writer(out)
    by_future = {}
    for cell, missing in todo:
        tag = hashlib.sha256("\0".join(v.label for v in missing).encode()).hexdigest()[:12]
        expected = provenance.identity([v.name for v in missing], cell.profile)  # checked by the worker
        future = client.submit(run_cell, cell, missing, expected, key=f"cell-{cell.key}-{tag}", pure=False)
        by_future[future] = (cell, missing)
    bar = tqdm(total=len(todo), desc=label, unit="cell", disable=not progress, dynamic_ncols=True)
    failed_now = 0
    try:
        for batch in as_completed(list(by_future), with_results=True, raise_errors=False).batches():
            rows: list[dict[str, Any]] = []
            for future, result in batch:
                cell, missing = by_future.pop(future)
                cell_rows = result if future.status == "finished" else _failed_rows(cell, missing, result)
                failed_now += any(r["status"] != "ok" for r in cell_rows)
                summary.fresh += any(r.get("fresh_process") for r in cell_rows)
                rows.extend(cell_rows)
            writer.write(rows)
            summary.ran += len(batch)
            bar.update(len(batch))
            bar.set_postfix(failed=failed_now, refresh=False)
    except KeyboardInterrupt:
        summary.interrupted = True
        for future in by_future:
            future.cancel()
    finally:
        bar.close()
    if summary.fresh:
        print(f"secuav-study: {summary.fresh} cells ran in a new process because their worker had loaded other code "
              "(restart the workers to run in-process again)", file=sys.stderr, flush=True)  # fmt: skip
    return summary

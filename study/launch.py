"""Run one study file into a directory: check it, save its inputs, run its cells on Dask, write the report.

``secuav-study run`` and ``secuav-study suite run`` (once per study of the suite) both call
:func:`run_study`, so a study run from the suite is the same run as one from the command line: the same
progress, stderr lines, closing JSON line and exit code (docs/interfaces.md).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
from pathlib import Path
from typing import Any

from secuav_common.loading import InputError

SMOKE_ENV = "SECUAV_STUDY_SMOKE"
SMOKE_CELLS = 2


def smoke() -> bool:
    """``SECUAV_STUDY_SMOKE=1``: every study cut to its first two cells (one seed, one leg, one hover point) of
    3 s (docs/bench.md): to try the commands of the docs, never a score (its directories say so and refuse
    real rows)."""
    return os.environ.get(SMOKE_ENV, "") not in ("", "0")


def load(path: Path, smoke: bool = False) -> tuple[Any, list[Any]]:
    """The study in ``path`` and its cells (with ``smoke``, the first two of a cut study); ``InputError`` names
    the field at fault."""
    from study.spec import expand, load_study

    study = load_study(path)
    if smoke:
        cut: dict[str, Any] = {"seeds": study.seed_list()[:1], "legs": study.legs[:1]}
        if study.mode == "offline" and study.recording is None and not study.recordings:
            cut["duration_s"] = min(3.0, study.duration_s or 3.0)
        if study.positions:
            cut["positions"] = study.positions[:1]
        study = study.model_copy(update=cut)
        print(f"secuav-study: {SMOKE_ENV} set: {path} cut to its first {SMOKE_CELLS} cells of one seed, one leg, "
              "3 s (not a score)", file=sys.stderr)  # fmt: skip
        return study, expand(study, str(path))[:SMOKE_CELLS]
    return study, expand(study, str(path))


def check_scheduler(url: str) -> None:
    """A tcp:// scheduler that refuses connections is named at once (Dask itself retries until its timeout)."""
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or parts.port is None:
        raise InputError("--scheduler", "", url, "expected tcp://HOST:PORT")
    try:
        socket.create_connection((parts.hostname, parts.port), timeout=10).close()
    except OSError as exc:
        raise InputError("--scheduler", "", url, f"cannot reach the scheduler: {exc.strerror or exc}") from None


def check_ports(ports: int | None, workers: int | None, scheduler: str | None) -> None:
    """``--ports BASE``: the embedded cluster's block of loopback ports must fit, and not beside a scheduler."""
    if ports is None:
        return
    if scheduler is not None:
        raise InputError("--ports", "", ports, "sets the embedded cluster's ports; not with --scheduler")
    from study.runner import cluster_ports

    last = ports + cluster_ports(ports, workers or os.cpu_count() or 1) - 1
    if not 1024 <= ports <= last <= 65535:
        raise InputError("--ports", "", ports, f"the block {ports}..{last} must lie in 1024..65535")


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run_study(path: Path, out: Path, *, workers: int | None = None, scheduler: str | None = None,
              ports: int | None = None, retry_failed: bool = False, progress: bool = True) -> int:  # fmt: skip
    """Run the cells of the study in ``path`` not yet in ``out``, then write the report; the exit code.

    0 when no cell failed, 1 when some did (they are in the results), 2 on bad input (one line on stderr),
    130 when interrupted (what finished is kept). Last on stdout, one JSON line (:class:`study.runner.Summary`).
    """
    from study import runner, store
    from study.bundle import save_inputs
    from study.report import write_report

    os.environ.setdefault("PYTHONWARNINGS", "ignore::DeprecationWarning")  # quiet workers
    try:
        from study.bundle import install_plugins

        for line in install_plugins(path):  # a bundle's plugins/ (secuav-study export --with-sources)
            print(f"secuav-study: {line}", file=sys.stderr, flush=True)
        study, cells = load(path, smoke=smoke())
        if workers is not None and not 1 <= workers <= 1024:
            raise InputError("--workers", "", workers, "must lie in 1..1024")
        if scheduler is not None:
            check_scheduler(scheduler)
        check_ports(ports, workers, scheduler)
        definition = {**study.model_dump(mode="json"), **({"smoke": True} if smoke() else {})}
        held = store.saved_study(out)
        if held is not None and held.get("name") != study.name:
            raise InputError(str(out), "study.json: name", held.get("name"),
                             f"this directory holds another study; use a new --out for {study.name!r}")  # fmt: skip
        if held is not None and bool(held.get("smoke")) != smoke():
            raise InputError(str(out), "study.json: smoke", bool(held.get("smoke")),
                             f"{SMOKE_ENV} runs and real ones never share a directory; use a new --out")  # fmt: skip
    except InputError as err:
        print(f"secuav-study: {err}", file=sys.stderr)
        return 2
    store.save_study(out, definition)
    save_inputs(out, study, path)
    done = store.done(out, retry_failed=retry_failed)
    signal.signal(signal.SIGTERM, _terminate)
    summary = runner.Summary(cells=len(cells))
    try:
        with runner.dask_client(workers, scheduler, ports) as client:
            summary = runner.run(cells, study.variants(), out, client, done, label=study.name, progress=progress)
    except KeyboardInterrupt:
        summary.interrupted = True
    except OSError as exc:  # the scheduler cannot be reached
        print(f"secuav-study: --scheduler {scheduler}: {exc}", file=sys.stderr)
        return 2
    summary.failed = runner.failed_cells(out)
    if summary.interrupted:
        kept = f"{summary.ran} cells done this run are kept in {out}"
        print(f"secuav-study: interrupted; {kept}; run again to go on", file=sys.stderr)
    else:
        report = write_report(out)
        print(f"report: {report}", file=sys.stderr)
    print(json.dumps(summary.as_dict(out)), flush=True)
    if summary.interrupted:
        return 130
    return 1 if summary.failed else 0

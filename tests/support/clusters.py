"""Real Dask clusters for the study tests: a ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1
(``plain_cluster``, and the ``dask_cluster`` fixture a test module imports to use it)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import free_tcp_port

BIN = Path(sys.executable).parent


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[tuple[str, list[str]]]:
    """A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1."""
    with plain_cluster() as cluster:
        yield cluster


@contextlib.contextmanager
def plain_cluster(env: dict[str, str] | None = None) -> Iterator[tuple[str, list[str]]]:
    """A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 (``env``: theirs)."""
    port = free_tcp_port()
    address = f"tcp://127.0.0.1:{port}"
    quiet: dict[str, Any] = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
    scheduler = [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]
    procs = [subprocess.Popen(scheduler, **quiet)]
    try:
        from distributed import Client

        for name in ("w1", "w2"):
            procs.append(subprocess.Popen(
                [str(BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--name", name, "--nworkers", "1",
                 "--nthreads", "1", "--no-dashboard"], **quiet,
            ))  # fmt: skip
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
            workers = sorted(client.scheduler_info()["workers"])
        yield address, workers
    finally:
        for proc in reversed(procs):
            proc.send_signal(signal.SIGINT)
        for proc in reversed(procs):
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

"""Run cells in a child process of the worker that loaded the current code.

A Dask worker keeps the modules it imported for its whole life: after an
estimator's file changes, a long-lived worker still computes with the old code
(and stamps the rows with the old hash). :func:`study.cells.run_cell` compares
the code hashes the client sent with the task against the worker's own; when
they differ, it hands the cell to :func:`run`, which runs it in a child process
started for those hashes: the child imports the code on the machine's disk now,
checks its own hashes against the client's again, and stays for the next cell
with the same hashes (one start per worker and code version, not per cell). A
task with other hashes ends the child and starts another (docs/bench.md,
"Long-lived workers and changed code").

Cells and rows travel as length-prefixed pickles on two pipes of their own
(never stdout: a plugin may print); the child ends when its request pipe
closes, so it never outlives the worker.

    python -m study.fresh_child REQUEST_FD REPLY_FD
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import select
import struct
import subprocess
import sys
import tempfile
import threading
from typing import IO, Any

TIMEOUT_S = 3600.0  # one cell: a closed-loop cell flies real time; an offline one takes seconds
_HEADER = struct.Struct("!Q")


def _send(pipe: IO[bytes], obj: Any) -> None:
    data = pickle.dumps(obj)
    pipe.write(_HEADER.pack(len(data)) + data)
    pipe.flush()


def _receive(pipe: IO[bytes]) -> Any:
    head = pipe.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError
    (size,) = _HEADER.unpack(head)
    return pickle.loads(pipe.read(size))


class _Child:
    """One child process serving cells for one set of code hashes."""

    def __init__(self) -> None:
        req_r, req_w = os.pipe()
        rep_r, rep_w = os.pipe()
        self.log = tempfile.TemporaryFile()  # noqa: SIM115  (the child's stderr, for the error line; lives with it)
        env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
        self.proc = subprocess.Popen([sys.executable, "-m", "study.fresh_child", str(req_r), str(rep_w)],
                                     pass_fds=(req_r, rep_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=self.log, env=env)  # fmt: skip
        os.close(req_r)
        os.close(rep_w)
        self.requests = os.fdopen(req_w, "wb")
        self.replies = os.fdopen(rep_r, "rb")

    def call(self, request: Any) -> Any:
        try:
            _send(self.requests, request)
            ready, _, _ = select.select([self.replies], [], [], TIMEOUT_S)
            if not ready:
                raise TimeoutError(f"no answer within {TIMEOUT_S:.0f} s")
            return _receive(self.replies)
        except (OSError, EOFError, TimeoutError, pickle.PickleError) as exc:
            self.close()
            self.log.seek(0)
            tail = " / ".join(self.log.read().decode(errors="replace").strip().splitlines()[-3:])
            raise RuntimeError(f"the new process for this cell failed ({type(exc).__name__}): {tail}") from None

    def close(self) -> None:
        for pipe in (self.requests, self.replies):
            with contextlib.suppress(OSError):
                pipe.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


_lock = threading.Lock()  # one cell at a time through the child (a worker may run several threads)
_child: tuple[str, _Child] | None = None


def run(cell: Any, variants: list[Any], expected: dict[str, Any]) -> list[dict[str, Any]]:
    """The rows of ``cell`` computed by the child for the client's hashes ``expected`` (started when needed);
    ``RuntimeError`` with the child's last stderr lines when it fails."""
    global _child
    key = json.dumps(expected, sort_keys=True)
    with _lock:
        if _child is not None and _child[0] != key:  # other code now: the old child is of no more use
            _child[1].close()
            _child = None
        if _child is None:
            _child = (key, _Child())
        try:
            rows: list[dict[str, Any]] = _child[1].call((cell, variants, expected))
        except RuntimeError:
            _child = None
            raise
        return rows

"""Run one cell in a new Python process, which imports the code on disk now.

A Dask worker keeps the modules it imported for its whole life: after an
estimator's file changes, a long-lived worker still computes with the old code
(and stamps the rows with the old hash). :func:`study.cells.run_cell` compares
the code hashes the client sent with the task against the worker's own; when
they differ, it runs the cell here instead, in a child process of the worker
that loads the current code, and checks that process's hashes against the
client's again (docs/bench.md, "Long-lived workers and changed code").

The cell and the rows travel as pickle files in a temporary directory (never
stdout: a plugin may print).

    python -m study.fresh IN.pkl OUT.pkl
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

TIMEOUT_S = 3600.0  # a closed-loop cell flies real time; an offline one takes seconds


def run(cell: Any, variants: list[Any], expected: dict[str, Any]) -> list[dict[str, Any]]:
    """The rows of ``cell`` computed by a new process (raises ``RuntimeError`` with its stderr tail if it fails)."""
    with tempfile.TemporaryDirectory(prefix="secuav-fresh-") as tmp:
        given, back = Path(tmp) / "in.pkl", Path(tmp) / "out.pkl"
        given.write_bytes(pickle.dumps((cell, variants, expected)))
        env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
        done = subprocess.run([sys.executable, "-m", "study.fresh", str(given), str(back)], capture_output=True,
                              text=True, timeout=TIMEOUT_S, check=False, env=env)  # fmt: skip
        if done.returncode != 0 or not back.is_file():
            tail = " / ".join(done.stderr.strip().splitlines()[-3:])
            raise RuntimeError(f"the fresh process for this cell exited {done.returncode}: {tail}")
        rows: list[dict[str, Any]] = pickle.loads(back.read_bytes())
        return rows


def main(argv: list[str]) -> int:
    from study.cells import run_cell

    given, back = Path(argv[0]), Path(argv[1])
    cell, variants, expected = pickle.loads(given.read_bytes())
    rows = run_cell(cell, variants, expected, fresh=False)  # fresh=False: never a process of a process
    tmp = back.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(rows))
    os.replace(tmp, back)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

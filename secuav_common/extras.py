"""Which package extra a command needs, said in one line when it is not installed.

``pip install secuav`` is the proxy and the libraries; the simulator, the demos,
the console and the studies come with extras (``secuav[sim]``, ``[demo]``,
``[console]``, ``[study]``, ``[all]``). A command whose extra is missing stops
with the install line to run, not with an ImportError traceback.
"""

from __future__ import annotations

import importlib.util
import sys

NEEDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "secuav-sim": ("sim", ("jsbsim",)),
    "secuav-demo": ("demo", ("jsbsim", "mavsdk")),
    "secuav-console": ("console", ("starlette", "uvicorn", "sse_starlette")),
    "secuav-study": ("study", ("dask", "distributed", "pandas")),
}


def missing(prog: str) -> str | None:
    """The one-line reason ``prog`` cannot run here, or None when its extra is installed."""
    extra, modules = NEEDS[prog]
    absent = [m for m in modules if importlib.util.find_spec(m) is None]
    if not absent:
        return None
    return f"{prog}: needs the [{extra}] extra ({', '.join(absent)} not installed): pip install 'secuav[{extra}]'"


def require(prog: str) -> None:
    """Exit 2 with that line when ``prog``'s extra is missing."""
    reason = missing(prog)
    if reason is not None:
        print(reason, file=sys.stderr)
        raise SystemExit(2)

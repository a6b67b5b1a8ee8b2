"""The SITL check scripts (scripts/sitl/) loaded as modules, for the tests of their pure parts."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = ROOT / "scripts" / "sitl"


def load_script(name: str) -> Any:
    """scripts/sitl/NAME.py as module NAME (the scripts import each other by that name)."""
    # the scripts set MAVLINK20 and MAVLINK_DIALECT for their own process; keep them out of the test run's
    saved = dict(os.environ)
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(SCRIPTS))
        os.environ.clear()
        os.environ.update(saved)

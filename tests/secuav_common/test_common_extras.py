"""A command whose package extra is missing says which one to install, in one line, exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from secuav_common import extras


def test_every_command_with_an_extra_runs_here_where_all_extras_are_installed() -> None:
    assert all(extras.missing(prog) is None for prog in extras.NEEDS)


def test_a_missing_extra_is_one_line_naming_the_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(extras.NEEDS, "secuav-sim", ("sim", ("jsbsim", "no_such_module_here")))
    assert extras.missing("secuav-sim") == (
        "secuav-sim: needs the [sim] extra (no_such_module_here not installed): pip install 'secuav[sim]'"
    )
    with pytest.raises(SystemExit) as exit_:
        extras.require("secuav-sim")
    assert exit_.value.code == 2


def test_the_real_command_stops_before_anything_else_when_its_extra_is_hidden() -> None:
    """secuav-sim in an interpreter where jsbsim cannot be imported (as in the proxy-only image)."""
    # A None entry in sys.modules is how Python marks a module as not importable: find_spec says None.
    code = "import sys; sys.modules['jsbsim'] = None; from flightsim.cli import main; sys.exit(main(['wall_hover']))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.strip().endswith("pip install 'secuav[sim]'"), done.stderr

"""Every shell command of docs/bench.md and docs/plugins.md, run as written (issue 35: a documented example
failed). Cheap through the documented ``SECUAV_STUDY_SMOKE=1`` (two cells of 3 s per study); the
placeholder scheduler ``tcp://HOST:8786`` is a real ``dask scheduler`` with two ``dask worker`` processes on
127.0.0.1; files the commands name are copied from the repository into the working directory."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.support.clusters import dask_cluster  # noqa: F401  (the fixture: a real scheduler + 2 workers)

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
PAGES = ("docs/bench.md", "docs/plugins.md")
FENCE = re.compile(r"^( *)```(\w*)\n(.*?)^\1```", re.S | re.M)  # a block indented in a list item too


def commands(page: str) -> list[tuple[list[str], list[str]]]:
    """The page's commands in order: each ``sh`` block's lines (continuations joined, comments dropped) and each
    ``text`` block's ``$ `` lines; with, for the latter, the output lines printed under them in the page."""
    out: list[tuple[list[str], list[str]]] = []
    for indent, lang, body in FENCE.findall((ROOT / page).read_text()):
        body = textwrap.dedent(body) if indent else body
        if lang == "sh":
            for line in body.replace("\\\n", " ").splitlines():
                argv = shlex.split(line, comments=True)
                if argv:
                    out.append((argv, []))
        elif lang == "text":
            for chunk in re.split(r"^\$ ", body, flags=re.M)[1:]:
                first, *shown = chunk.splitlines()
                out.append((shlex.split(first), shown))
    return out


def test_the_pages_have_commands_to_run() -> None:
    bench = [" ".join(a) for a, _ in commands("docs/bench.md")]
    assert any("suite run" in c and "--split tuning" in c for c in bench)
    assert sum("--add" in c for c in bench) == 2 and all(c.count("--add") == 1 for c in bench if "--add" in c)
    assert any(a[0] == "secuav-plugins" for a, _ in commands("docs/plugins.md"))


def _argv(argv: list[str], scheduler: str) -> list[str]:
    argv = [a.replace("tcp://HOST:8786", scheduler) for a in argv]
    if argv[0] == "python":
        return [sys.executable, *argv[1:]]
    return [str(BIN / argv[0]), *argv[1:]] if (BIN / argv[0]).exists() else argv


def _same(line: str) -> str:
    return " ".join(line.split())


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("page", PAGES)
def test_every_command_of_the_page_runs(page: str, tmp_path: Path, dask_cluster: tuple[str, list[str]]) -> None:  # noqa: F811
    scheduler, _ = dask_cluster
    # the example plugin's folder, as a user's checkout has it (its study, its tests, its project for --source)
    shutil.copytree(ROOT / "examples/plugin", tmp_path / "examples/plugin",
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))  # fmt: skip
    env = {**os.environ, "SECUAV_STUDY_SMOKE": "1", "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    ran = 0
    for argv, shown in commands(page):
        done = subprocess.run(_argv(argv, scheduler), cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=900, check=False)  # fmt: skip
        said = f"{shlex.join(argv)}\nstdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-3000:]}"
        assert done.returncode == 0, said
        printed = {_same(line) for line in done.stdout.splitlines()}
        for line in shown:  # what the page shows it printing (a "..." line is an abbreviation)
            if line.strip() and "..." not in line:
                assert _same(line) in printed, f"{page}: {line!r} not printed by {shlex.join(argv)}\n{said}"
        ran += 1
    assert ran >= (9 if page == "docs/bench.md" else 3)

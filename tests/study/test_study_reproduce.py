"""Reproduction on a clean machine: ``secuav-study export --with-sources`` ships the plugins' sources, and
``secuav-study run BUNDLE/study.yaml`` in an environment without the plugin installs it and computes the rows again.

The clean machine is a new venv (``python -m venv``: its own interpreter prefix, pip and site-packages) whose
site-packages links to the distributions of this environment, secuav and its dependencies (building secuav's
dependency tree from an index for a test would take minutes and need the network). The plugin under test,
``idplug``, is in no site-packages at all: the author's side sees it only through PYTHONPATH, the clean side only
through the bundle.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pandas as pd
import pytest

BIN = Path(sys.executable).parent

MINE = '''"""mine: the example plugin's Huber estimator with a default of its own."""
from secuav_example_plugin.huber import Huber


class Mine(Huber):
    name = "mine"

    def __init__(self, model, *, huber_k: float = 0.8, **params):
        super().__init__(model, huber_k=huber_k, **params)
'''

PYPROJECT = """[build-system]
requires = ["setuptools"]
build-backend = "setuptools.build_meta"

[project]
name = "idplug"
version = "0.3.0"
requires-python = ">=3.11"

[project.entry-points."secuav.estimators"]
mine = "idplug.mine:Mine"

[tool.setuptools]
packages = ["idplug"]
"""

STUDY = """
name: reproduce
scenario: anchors6_small
duration_s: 6
legs: [moving]
estimators: [mine]
seeds: [3]
attacks:
  - none
  - profile: anchors-moving-bias
"""


def _author(tmp_path: Path) -> tuple[Path, Path]:
    """The plugin's project folder, and a site folder where the author's Python finds it (with its metadata)."""
    project = tmp_path / "idplug-project"
    (project / "idplug").mkdir(parents=True)
    (project / "pyproject.toml").write_text(PYPROJECT)
    (project / "idplug" / "__init__.py").write_text("")
    (project / "idplug" / "mine.py").write_text(MINE)
    site_dir = tmp_path / "author-site"
    info = site_dir / "idplug-0.3.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: idplug\nVersion: 0.3.0\n")
    (info / "entry_points.txt").write_text("[secuav.estimators]\nmine = idplug.mine:Mine\n")
    (site_dir / "idplug").symlink_to(project / "idplug")
    return project, site_dir


def _clean_venv(where: Path) -> Path:
    """A new venv that sees this environment's site-packages (secuav, numpy, ...) and nothing installed since."""
    subprocess.run([sys.executable, "-m", "venv", str(where)], check=True, capture_output=True, timeout=300)
    python = where / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    ours = Path(sysconfig.get_paths()["purelib"])
    for entry in ours.iterdir():  # a link to each of them, where the new venv has none of its own (pip, setuptools)
        if not (Path(purelib) / entry.name).exists():
            (Path(purelib) / entry.name).symlink_to(entry)
    return python


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return {**env, "PYTHONWARNINGS": "ignore::DeprecationWarning", **extra}


FIGURES = ["rmse_m", "mean_error_m", "max_error_m", "valid_fraction", "estimator_code", "code_key"]


@pytest.mark.xdist_group("dask_study")
@pytest.mark.slow
def test_a_bundle_with_the_plugins_source_reproduces_its_rows_in_a_clean_venv(tmp_path: Path) -> None:
    from study.store import load

    project, author_site = _author(tmp_path)
    author = _env(PYTHONPATH=str(author_site))
    study = tmp_path / "reproduce.yaml"
    study.write_text(STUDY)
    out, bundle = tmp_path / "out", tmp_path / "bundle"
    run = [str(BIN / "secuav-study"), "run", str(study), "--out", str(out), "--workers", "1", "--no-progress"]
    first = subprocess.run(run, capture_output=True, text=True, timeout=400, env=author, check=False)
    assert first.returncode == 0, first.stderr
    export = subprocess.run([str(BIN / "secuav-study"), "export", str(out), str(bundle), "--source", str(project)],
                            capture_output=True, text=True, timeout=300, env=author, check=False)  # fmt: skip
    assert export.returncode == 0, export.stderr
    shipped = {e["dist"]: e for e in json.loads((bundle / "plugins" / "plugins.json").read_text())}
    # idplug from --source; the example plugin (its primitive attacked) from the folder it was installed from
    assert set(shipped) == {"idplug", "secuav-example-plugin"}
    assert shipped["idplug"]["file"] == "idplug-0.3.0.tar.gz" and shipped["idplug"]["version"] == "0.3.0"
    assert not (project / "idplug.egg-info").exists()  # the author's folder is left as it was

    python = _clean_venv(tmp_path / "clean")
    gone = subprocess.run([str(python), "-c", "import idplug"], capture_output=True, text=True, env=_env())
    assert gone.returncode != 0 and "No module named 'idplug'" in gone.stderr  # a machine without the plugin
    again = tmp_path / "again"
    clean_run = [str(python), "-m", "study", "run", str(bundle / "study.yaml"), "--out", str(again), "--workers",
                 "1", "--no-progress"]  # fmt: skip
    done = subprocess.run(clean_run, capture_output=True, text=True, timeout=600, env=_env(), check=False)
    assert done.returncode == 0, done.stderr
    assert f"installed plugin idplug 0.3.0 from {bundle / 'plugins' / 'idplug-0.3.0.tar.gz'}" in done.stderr
    assert "secuav-example-plugin" not in done.stderr  # installed there already: left alone

    then, now = load(out).set_index(["cell", "estimator"]), load(str(again)).set_index(["cell", "estimator"])
    assert (now["status"] == "ok").all() and len(now) == len(then) == 6  # two cells x (mine, ls, ekf)
    assert (now.loc[(slice(None), "mine"), "estimator_dist"] == "idplug").all()
    pd.testing.assert_frame_equal(now.sort_index()[FIGURES], then.sort_index()[FIGURES])

    twice = subprocess.run(clean_run, capture_output=True, text=True, timeout=600, env=_env(), check=False)
    assert twice.returncode == 0 and "installed plugin" not in twice.stderr, twice.stderr
    assert json.loads(twice.stdout.splitlines()[-1])["skipped"] == 2


def test_a_plugin_without_a_known_source_is_one_line(tmp_path: Path) -> None:
    from study.bundle import installed_source

    assert installed_source("secuav-example-plugin") == Path(__file__).resolve().parents[2] / "examples" / "plugin"
    assert installed_source("numpy") is None  # from an index: no folder to ship

"""Plugin discovery (secuav_common.plugins): lazy, per process, and a broken plugin costs one line.

The broken plugin here is a real distribution's metadata (a ``.dist-info`` folder with
``entry_points.txt``) on ``PYTHONPATH`` of a fresh interpreter: exactly what
``importlib.metadata`` reads for an installed package whose code fails to import.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import pytest

from secuav_common import plugins

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def _broken_dist(where: Path) -> Path:
    info = where / "broken_bench-0.3.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-bench\nVersion: 0.3\n")
    (info / "entry_points.txt").write_text(
        "[secuav.estimators]\nbroken = broken_bench_missing.est:Thing\n"
        "[secuav.primitives]\nbroken_kind = broken_bench_missing.prim:Thing\n"
    )
    return where


def _run(args: list[str], path: Path | None = None) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    if path is not None:
        env["PYTHONPATH"] = str(path)
    return subprocess.run(args, capture_output=True, text=True, timeout=120, env=env, cwd=ROOT, check=False)


def test_a_broken_plugin_is_one_line_and_the_built_ins_keep_working(tmp_path: Path) -> None:
    where = _broken_dist(tmp_path)
    code = "import estimators; print(','.join(estimators.names()))"
    done = _run([sys.executable, "-c", code], where)
    assert done.returncode == 0, done.stderr
    assert "ekf" in done.stdout.split(",") and "broken" not in done.stdout
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, done.stderr
    assert "'broken'" in lines[0] and "broken-bench 0.3" in lines[0] and "ModuleNotFoundError" in lines[0]


def test_a_broken_plugin_is_not_imported_when_not_named(tmp_path: Path) -> None:
    where = _broken_dist(tmp_path)
    code = "import estimators; print(estimators.known('ekf'), estimators.known('secekf'))"
    done = _run([sys.executable, "-c", code], where)
    assert done.stdout.split() == ["True", "True"] and done.stderr == ""


def test_the_listing_names_a_broken_plugin_and_exits_1(tmp_path: Path) -> None:
    done = _run([str(BIN / "secuav-plugins")], _broken_dist(tmp_path))
    assert done.returncode == 1
    assert "broken_kind" in done.stderr and "broken-bench 0.3" in done.stderr
    assert "secuav.estimators" in done.stdout


def test_a_profile_naming_a_broken_primitive_is_one_clear_error(tmp_path: Path) -> None:
    profile = tmp_path / "p.yaml"
    profile.write_text("name: p\nrules:\n  - {kind: broken_kind, target: {message: DISTANCE_SENSOR}}\n")
    done = _run([str(BIN / "secuav-attack"), "validate", str(profile)], _broken_dist(tmp_path / "site"))
    assert done.returncode == 1
    assert "rules[0].kind" in done.stderr and "unknown primitive" in done.stderr
    assert "broken_kind" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize(
    ("text", "ok"),
    [("pkg.mod:Class", True), ("pkg:Class.inner", True), ("ekf", False), ("pkg.mod:", False), ("a b:c", False)],
)
def test_module_references(text: str, ok: bool) -> None:
    assert plugins.is_ref(text) is ok


def test_a_reference_that_does_not_import_says_why() -> None:
    with pytest.raises(plugins.PluginError, match="No module named"):
        plugins.load_ref("secuav_no_such_module.x:Y")


def test_estimators_by_module_reference() -> None:
    from estimators import registry

    assert registry.get("estimators.ekf:ExtendedKalman") is registry.get("ekf")
    with pytest.raises(ValueError, match=r"not an estimators\.base\.Estimator"):
        registry.get("estimators.ekf:np")


def test_source_hash_follows_the_code_of_the_class_and_its_bases() -> None:
    from estimators import registry

    assert registry.code_hash("ekf") != registry.code_hash("ls")  # own module differs
    assert len(registry.code_hash("ekf")) == 16


def test_declared_parameters_come_from_the_signatures() -> None:
    from estimators import registry

    params = {p.name: p for p in registry.parameters(registry.get("secekf"))}
    assert params["window"].default == 10 and params["alpha"].default == 0.01
    assert (params["alpha"].low, params["alpha"].high) == registry.SHARED_RANGES["alpha"]


def test_a_listing_entry_is_json_whatever_the_defaults_and_ranges() -> None:
    import json
    import math

    from estimators import registry
    from estimators.base import Estimator

    class Odd(Estimator):
        """``odd``: an estimator whose default and range JSON cannot hold as they are."""

        name = "odd"
        param_ranges: ClassVar[dict[str, tuple[float, float]]] = {"gain": (0.0, math.inf)}

        def __init__(self, model: object, *, gain: float = math.nan, shape: tuple[int, int] = (2, 3),
                     **params: object) -> None:  # fmt: skip
            super().__init__(model, **params)  # type: ignore[arg-type]

    params = {p.name: p.as_json() for p in registry.parameters(Odd)}
    assert params["gain"] == {"default": "nan", "low": 0.0, "high": None}  # unbounded above
    assert params["shape"] == {"default": "(2, 3)", "low": None, "high": None}
    assert params["alpha"]["low"] == registry.SHARED_RANGES["alpha"][0]
    json.dumps(params, allow_nan=False)  # what the console's JSONResponse does
    assert registry.summary(Odd) == "an estimator whose default and range JSON cannot hold as they are."
    assert registry.summary(registry.get("ekf")).startswith("constant-velocity extended Kalman")  # its module's

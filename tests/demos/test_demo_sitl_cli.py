"""``secuav-demo height-hold --autopilot ardupilot`` without a SITL binary (CI has none): flags, the missing-binary
error and its exit code, and what it needs at run time found in the package. The flight itself needs ArduCopter
SITL; its measured matrix is in docs/ardupilot.md."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from demos import cli, sitl
from demos.height_hold import SCENARIO
from secuav_common.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
DEMO = Path(sys.executable).parent / "secuav-demo"


def _env(cache: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "ARDUPILOT_BIN"}
    return {**env, "SECUAV_ARDUPILOT_CACHE": str(cache), **extra}


def _build(folder: Path, copter_parm: bool = True) -> Path:
    """A cache entry as ``ardupilot.sh build`` leaves it: an executable, ArduPilot's copter.parm, version files.
    The executable is never run by these tests except where it is /bin/false."""
    folder.mkdir(parents=True, exist_ok=True)
    binary = folder / "arducopter"
    binary.write_text("#!/bin/sh\nexit 1\n")
    binary.chmod(0o755)
    if copter_parm:
        (folder / "copter.parm").write_text("FRAME_CLASS 1\n")
    (folder / "version").write_text("ArduCopter V4.7.0-dev\n")
    (folder / "commit").write_text("2598e9d4b2\n")
    return binary


def test_help_lists_height_hold_and_the_sitl_flags() -> None:
    done = subprocess.run([str(DEMO), "--help"], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    for text in ("height-hold", "--autopilot {flightsim,ardupilot,px4}", "--sitl-binary", "--instance", "--speedup"):
        assert text in done.stdout


def test_no_binary_is_one_line_naming_what_to_run_and_exit_3(tmp_path: Path) -> None:
    done = subprocess.run([str(DEMO), "height-hold", "--out", str(tmp_path / "out")], env=_env(tmp_path / "cache"),
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == cli.NO_SITL == 3, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert str(tmp_path / "cache" / "latest" / "arducopter") in lines[0]
    assert "scripts/sitl/ardupilot.sh build SOURCE" in lines[0] and "--sitl-binary" in lines[0]
    assert not (tmp_path / "out").exists()  # nothing flown, nothing written


@pytest.mark.parametrize(("flag", "origin"), [("--sitl-binary", "--sitl-binary"), (None, "ARDUPILOT_BIN")])
def test_a_named_binary_that_is_not_there_says_where_the_path_came_from(
    tmp_path: Path, flag: str | None, origin: str
) -> None:
    missing = tmp_path / "nothing" / "arducopter"
    argv, extra = ["height-hold"], {"ARDUPILOT_BIN": str(missing)}
    if flag:
        argv, extra = [*argv, flag, str(missing)], {}
    done = subprocess.run([str(DEMO), *argv], env=_env(tmp_path, **extra), capture_output=True, text=True,
                          timeout=60, check=False)  # fmt: skip
    assert done.returncode == 3 and f"no ArduCopter SITL binary at {missing} ({origin})" in done.stderr, done


def test_a_binary_without_copter_parm_is_refused_with_exit_3(tmp_path: Path) -> None:
    binary = _build(tmp_path / "build", copter_parm=False)
    done = subprocess.run([str(DEMO), "height-hold", "--sitl-binary", str(binary)], env=_env(tmp_path / "cache"),
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 3 and "no copter.parm beside" in done.stderr, done


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["wall-hover", "--autopilot", "ardupilot"], "wall-hover flies on flightsim, not ardupilot"),
        (["height-hold", "--autopilot", "flightsim"], "height-hold flies on ardupilot, not flightsim"),
        (["localise", "--instance", "3"], "--instance: only with --autopilot ardupilot"),
        (["formation", "--sitl-binary", "x", "--speedup", "2"], "--sitl-binary, --speedup: only with"),
        (["height-hold", "--seed", "4"], "--seed: flightsim's noise seed"),
        (["height-hold", "--instance", "-1"], "--instance: a non-negative integer"),
        (["height-hold", "--speedup", "0"], "--speedup: a positive number"),
        (["height-hold", "--autopilot", "px4"], "height-hold flies on ardupilot, not px4"),
    ],
)
def test_flags_that_do_not_fit_the_demo_are_bad_flags(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_each_demo_takes_its_own_autopilot_by_default() -> None:
    for demo, module in cli.DEMOS.items():
        args = cli.build_parser().parse_args([demo])
        assert cli.check_autopilot(args) is None
        assert args.autopilot == module.AUTOPILOTS[0]
    assert cli.DEMOS["height-hold"].AUTOPILOTS == ("ardupilot",)


def test_sitl_options_resolve_flag_then_env_then_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cached = _build(tmp_path / "cache" / "2598e9d4b2")
    (tmp_path / "cache" / "latest").symlink_to(cached.parent)
    from_env, from_flag = _build(tmp_path / "env"), _build(tmp_path / "flag")
    monkeypatch.setenv("SECUAV_ARDUPILOT_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("ARDUPILOT_BIN", raising=False)
    args = cli.build_parser().parse_args(["height-hold"])
    assert cli.check_autopilot(args) is None
    assert cli.sitl_options(args) == sitl.SitlOptions(tmp_path / "cache" / "latest" / "arducopter", 7, 1.0)
    monkeypatch.setenv("ARDUPILOT_BIN", str(from_env))
    assert sitl.find_binary() == from_env
    args = cli.build_parser().parse_args(["height-hold", "--sitl-binary", str(from_flag), "--instance", "4",
                                          "--speedup", "2"])  # fmt: skip
    assert cli.check_autopilot(args) is None
    assert cli.sitl_options(args) == sitl.SitlOptions(from_flag, 4, 2.0)
    assert sitl.build_info(from_flag) == {"version": "ArduCopter V4.7.0-dev", "commit": "2598e9d4b2"}
    assert cli.sitl_options(cli.build_parser().parse_args(["wall-hover"])) is None


def test_the_launch_applies_copter_parm_then_the_packaged_rangefinders(tmp_path: Path) -> None:
    binary = _build(tmp_path / "build")
    argv = sitl.command(binary, 7, sysid=2, speedup=1.5, extra_params=[tmp_path / "mine.parm"])
    assert argv[0] == str(binary) and "-I7" in argv and "-w" in argv
    assert argv[argv.index("--sysid") + 1] == "2" and argv[argv.index("--speedup") + 1] == "1.5"
    defaults = argv[argv.index("--defaults") + 1].split(",")
    assert defaults == [str(binary.parent / "copter.parm"), str(sitl.PARAMS), str(tmp_path / "mine.parm")]
    assert (sitl.tcp_port(7), sitl.tcp_port(7, serial=1)) == (5830, 5832)


def test_the_rangefinder_parameters_ship_in_the_package() -> None:
    """One file, in the package, covered by pyproject's package-data, giving the scenario's three sensors."""
    assert sitl.PARAMS.is_file() and sitl.PARAMS.parent.parent == Path(sitl.__file__).resolve().parent
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    relative = sitl.PARAMS.relative_to(Path(sitl.__file__).resolve().parent)
    assert any(relative.match(glob) for glob in package_data["demos"]), package_data.get("demos")
    assert not list((ROOT / "scripts").rglob("*.parm")), "a second copy of the parameter file"
    values = dict(line.split() for line in sitl.PARAMS.read_text().splitlines() if line and not line.startswith("#"))
    ids = [int(s.id) for s in load_scenario(SCENARIO).vehicles[0].sensors.rangefinders]
    assert ids == [0, 1, 2]
    for n in (1, 2, 3):  # RNGFNDn is DISTANCE_SENSOR id n-1, pointing down (25) as the scenario mounts it
        assert (values[f"RNGFND{n}_TYPE"], values[f"RNGFND{n}_ORIENT"]) == ("100", "25")
    assert values["SIM_SONAR_ROT"] == "25"


def test_the_shell_recipe_runs_the_package_launcher(tmp_path: Path) -> None:
    """``scripts/sitl/ardupilot.sh run`` is ``python -m demos.sitl run``: same parameters, same missing-binary line."""
    script = ROOT / "scripts" / "sitl" / "ardupilot.sh"
    done = subprocess.run(["bash", str(script), "run", "1"], env=_env(tmp_path / "cache"), capture_output=True,
                          text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 3 and "no ArduCopter SITL binary at" in done.stderr, done
    done = subprocess.run([sys.executable, "-m", "demos.sitl", "params"], capture_output=True, text=True,
                          timeout=60, check=False, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0 and Path(done.stdout.strip()) == sitl.PARAMS


async def test_a_sitl_that_stops_at_once_fails_ready_naming_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SECUAV_ARDUPILOT_CACHE", str(tmp_path / "cache"))
    binary = _build(tmp_path / "build")  # exits 1 at once, as a SITL that cannot start does
    async with sitl.Sitl(binary, 9) as sim:
        with pytest.raises(RuntimeError, match=r"SITL instance 9 exited \(1\): see .*run/9/sitl.log"):
            await sim.ready(10.0)


@pytest.mark.parametrize(("argv", "env"), [(["run", "0"], {}), (["run", "1"], {"SITL_INSTANCE": "-1"}),
                                           (["run", "1"], {"SITL_SPEEDUP": "fast"})])  # fmt: skip
def test_the_launcher_refuses_bad_counts_and_environment_with_exit_2(
    argv: list[str], env: dict[str, str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    assert sitl.main(argv) == 2
    assert capsys.readouterr().err.startswith("demos.sitl: ")

"""``secuav-demo vision --autopilot px4`` without a PX4 binary (CI has none): the missing-binary line and exit 3,
the flags that do not fit, where the binary is looked for, and the truth scoring on a recorded shape of flight.
The flight itself needs PX4 SIH; its measured matrix is in docs/px4.md."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from demos import cli, px4, vision
from demos.flight import Case

DEMO = Path(sys.executable).parent / "secuav-demo"


def _env(cache: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PX4_BIN"}
    return {**env, "SECUAV_PX4_CACHE": str(cache), **extra}


def _build(folder: Path) -> Path:
    """A cache entry as ``px4.sh build`` leaves it: bin/px4, etc/, commit. Never run by these tests."""
    (folder / "bin").mkdir(parents=True)
    (folder / "etc").mkdir()
    binary = folder / "bin" / "px4"
    binary.write_text("#!/bin/sh\nexit 1\n")
    binary.chmod(0o755)
    (folder / "commit").write_text("v1.17.0-1-g5b73eed759\n")
    return binary


def test_no_binary_is_one_line_naming_what_to_run_and_exit_3(tmp_path: Path) -> None:
    done = subprocess.run([str(DEMO), "vision", "--out", str(tmp_path / "out")], env=_env(tmp_path / "cache"),
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == cli.NO_SITL == 3, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert str(tmp_path / "cache" / "latest" / "bin" / "px4") in lines[0]
    assert "scripts/sitl/px4.sh build SOURCE" in lines[0]
    assert not (tmp_path / "out").exists()  # nothing flown, nothing written


def test_a_binary_without_etc_beside_it_is_refused_with_exit_3(tmp_path: Path) -> None:
    binary = _build(tmp_path / "build")
    (tmp_path / "build" / "etc").rmdir()
    done = subprocess.run([str(DEMO), "vision", "--sitl-binary", str(binary)], env=_env(tmp_path / "cache"),
                          capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 3 and "no etc/ beside its bin/" in done.stderr, done


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["vision", "--autopilot", "ardupilot"], "vision flies on px4, not ardupilot"),
        (["height-hold", "--autopilot", "px4"], "height-hold flies on ardupilot, not px4"),
        (["vision", "--speedup", "2"], "--speedup: only with --autopilot ardupilot"),
        (["vision", "--seed", "3"], "--seed: flightsim's noise seed; PX4 SIH draws its own"),
    ],
)
def test_flags_that_do_not_fit_are_bad_flags(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_px4_options_resolve_flag_then_env_then_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cached = _build(tmp_path / "cache" / "5b73eed759")
    (tmp_path / "cache" / "latest").symlink_to(cached.parent.parent)
    from_env, from_flag = _build(tmp_path / "env"), _build(tmp_path / "flag")
    monkeypatch.setenv("SECUAV_PX4_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("PX4_BIN", raising=False)
    args = cli.build_parser().parse_args(["vision"])
    assert cli.check_autopilot(args) is None and args.autopilot == "px4"
    assert cli.px4_options(args) == px4.Px4Options(tmp_path / "cache" / "latest" / "bin" / "px4", px4.DEFAULT_INSTANCE)
    monkeypatch.setenv("PX4_BIN", str(from_env))
    assert px4.find_binary() == from_env
    args = cli.build_parser().parse_args(["vision", "--sitl-binary", str(from_flag), "--instance", "7"])
    assert cli.check_autopilot(args) is None
    assert cli.px4_options(args) == px4.Px4Options(from_flag, 7)
    assert px4.build_info(from_flag) == {"commit": "v1.17.0-1-g5b73eed759"}
    assert cli.px4_options(cli.build_parser().parse_args(["height-hold"])) is None


def test_the_scoring_measures_true_drift_and_the_estimate_against_truth() -> None:
    """A vehicle that flies north at 0.2 m/s while its estimate stays on the setpoint: drift and estimate error
    grow with the ramp, the estimate's distance from its setpoint stays zero."""
    t0, rate = 100.0, 0.2
    times = [t0 - 1.0 + k * 0.05 for k in range(int(21 / 0.05) + 1)]
    truth = [(t, 1.0 + rate * max(0.0, t - t0), -2.0, -5.0) for t in times]
    estimate = [(t + 0.01, 1.0, -2.0, -5.0) for t in times]
    f = vision.score(truth, estimate, (1.0, -2.0, -5.0), t0, t0 + 20.0, t0, {"rate_m_s": rate},
                     Case("vehicle-vision-ramp", "off"))  # fmt: skip
    assert f["hold_point_ned_m"] == [1.0, -2.0]
    assert math.isclose(f["drift_m"]["final"], 4.0, abs_tol=0.02)
    assert math.isclose(f["drift_m"]["max"], 4.0, abs_tol=0.02)
    assert math.isclose(f["drift_m"]["rms"], 4.0 / math.sqrt(3), rel_tol=0.02)  # a ramp's rms is max/sqrt(3)
    assert math.isclose(f["estimate_error_m"]["final"], 4.0, abs_tol=0.02)
    assert f["estimate_from_setpoint_m"]["max"] == 0.0
    assert f["lie_at_end_m"] == 4.0 and f["north_displacement_final_m"] == pytest.approx(4.0, abs=0.02)
    assert f["north_rate_m_s"] == pytest.approx(rate, abs=1e-3)  # the truth moved at the ramp's rate
    held = vision.score(estimate, estimate, (1.0, -2.0, -5.0), t0, t0 + 20.0, None, {}, Case(None, "secekf"))
    assert held["drift_m"]["max"] == 0.0 and held["lie_at_end_m"] == 0.0 and held["north_rate_m_s"] == 0.0


def test_the_parameters_file_turns_on_vision_and_off_gps() -> None:
    lines = [ln.split() for ln in vision.PARAMS.read_text().splitlines() if ln.startswith("param set")]
    values = {w[2]: w[3] for w in lines}
    assert values["EKF2_EV_CTRL"] == "1" and values["EKF2_GPS_CTRL"] == "0" and values["EKF2_HGT_REF"] == "0"

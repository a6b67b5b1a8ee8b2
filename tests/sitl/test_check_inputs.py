"""The pure parts of scripts/sitl/check_inputs.py, which measures the MAVLink input paths of ArduPilot and PX4
on SITL (docs/vehicle-inputs.md): the geometry its feeds are computed with, the ramped offset, the verdict
on a report, and that every parameter file it names exists and says what the docs table says. The check
itself needs the SITL binaries and is not run here."""

from __future__ import annotations

import math
import re
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.support.sitl_scripts import load_script

check_inputs = load_script("check_inputs")
ROOT = Path(__file__).resolve().parents[2]


@given(st.floats(-60, 60), st.floats(-179, 179), st.floats(-500, 500), st.floats(-500, 500))
def test_shifted_and_north_east_are_inverse(lat: float, lon: float, north: float, east: float) -> None:
    lat2, lon2 = check_inputs.shifted(lat, lon, north, east)
    n, e = check_inputs.north_east_m(lat2, lon2, lat, lon)
    assert math.isclose(n, north, abs_tol=1e-6)
    # east is measured at the start's latitude, and shifted uses the same one
    assert math.isclose(e, east, abs_tol=1e-6)


def test_one_microdegree_of_latitude_is_eleven_centimetres() -> None:
    n, e = check_inputs.north_east_m(-35.000001, 149.0, -35.0, 149.0)
    assert math.isclose(n, -0.1113, abs_tol=1e-3) and e == 0


def test_gps_week_of_a_known_time() -> None:
    # 2026-11-27 00:00:00 UTC is a Friday, 5 days into GPS week 2446 (17,127 days after 1980-01-06);
    # GPS time is 18 leap seconds ahead
    week, ms = check_inputs.gps_week(1_795_737_600)
    assert week == 2446
    assert ms == (5 * 86400 + 18) * 1000


def test_ramp_holds_then_moves_linearly_then_holds() -> None:
    r = check_inputs.Ramp(3.0)
    assert r.at(100.0) == 3.0 and r.rate(100.0) == 0.0
    r.to(8.0, 10.0, 2.0)
    assert r.at(9.0) == 3.0
    assert math.isclose(r.at(11.0), 5.5)
    assert math.isclose(r.rate(11.0), 2.5)
    assert r.at(12.5) == 8.0 and r.rate(12.5) == 0.0
    r.to(3.0, 20.0, 0.0)  # a step
    assert r.at(20.0) == 8.0 and r.at(20.001) == 3.0


def test_ramp_started_mid_ramp_continues_from_where_it_is() -> None:
    r = check_inputs.Ramp(0.0)
    r.to(10.0, 0.0, 10.0)
    r.to(0.0, 5.0, 5.0)  # turned back half way
    assert math.isclose(r.at(5.0), 5.0)
    assert math.isclose(r.at(7.5), 2.5)


def test_verdict() -> None:
    v = check_inputs.verdict
    assert v(5.0, 5.0) and v(4.1, 5.0) and v(-5.9, -5.0)
    assert not v(3.9, 5.0) and not v(0.0, 5.0) and not v(-5.0, 5.0)
    assert v(0.09, 0.0) and not v(0.2, 0.0)  # 0.1 m at least
    assert not v(None, 5.0) and not v(math.nan, 5.0)


def test_median_between() -> None:
    series = [(0.0, 1.0), (1.0, 2.0), (2.0, 30.0), (3.0, 4.0)]
    assert check_inputs.median_between(series, 0.5, 3.0) == 4.0
    assert check_inputs.median_between(series, 5.0, 6.0) is None


@given(st.floats(-3.1, 3.1))
def test_ned_to_body_under_yaw(yaw: float) -> None:
    q = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    fwd, right, down = check_inputs.ned_to_body((1.0, 0.0, 0.0), q)  # north, in the body frame
    assert math.isclose(fwd, math.cos(yaw), abs_tol=1e-9)
    assert math.isclose(right, -math.sin(yaw), abs_tol=1e-9)
    assert math.isclose(down, 0.0, abs_tol=1e-9)
    assert math.isclose(check_inputs.quat_to_euler(q)[2], yaw, abs_tol=1e-9)


def test_truth_of_both_autopilots() -> None:
    sim = mav2.MAVLink_sim_state_message(q1=1, q2=0, q3=0, q4=0, roll=0, pitch=0, yaw=0, xacc=0, yacc=0, zacc=0,
                                         xgyro=0, ygyro=0, zgyro=0, lat=-35.4, lon=149.2, alt=584.0,
                                         std_dev_horz=1, std_dev_vert=1, vn=1.0, ve=2.0, vd=3.0,
                                         lat_int=-355000000, lon_int=1491000000)
    t = check_inputs.truth_of(sim)
    assert (t.lat, t.lon, t.alt_m, t.vel_ned) == (-35.5, 149.1, 584.0, (1.0, 2.0, 3.0))  # the int fields win
    hil = mav2.MAVLink_hil_state_quaternion_message(0, [1, 0, 0, 0], 0, 0, 0, 473977420, 85455940, 488000,
                                                    100, -200, 50, 0, 0, 0, 0, 0)
    t = check_inputs.truth_of(hil)
    assert math.isclose(t.lat, 47.397742) and t.alt_m == 488.0 and t.vel_ned == (1.0, -2.0, 0.5)
    assert check_inputs.truth_of(mav2.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 3)) is None


def _settings(path: Path, pattern: str) -> dict[str, float]:
    out = {}
    for line in path.read_text().splitlines():
        m = re.match(pattern, line)
        if m:
            out[m.group(1)] = float(m.group(2))
    return out


def test_every_group_names_a_parameter_file_that_sets_what_its_rows_say() -> None:
    """Each parameter a row names with its value (as docs/vehicle-inputs.md prints them) is set to that value
    in the group's parameter file."""
    for ap, pattern in ((check_inputs.ArduPilot(ROOT, 6), r"^(\w+)\s+(-?[\d.]+)"),
                        (check_inputs.PX4(ROOT, 4), r"^param set (\w+) (-?[\d.]+)")):
        for group in ap.groups:
            values = _settings(group.param_file, pattern)
            named = 0
            for path in group.paths:
                for name, value in re.findall(r"\b([A-Z][A-Z0-9]+_[A-Z0-9_]+) (-?\d+)\b", path.params):
                    assert values.get(name) == float(value), (group.param_file, name, value)
                    named += 1
            assert named >= 2, group.name

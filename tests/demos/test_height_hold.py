"""The ArduPilot height-hold controller's pure parts and the scoring of its flights; no SITL binary needed.

The flight itself (``secuav-demo height-hold``) needs ArduCopter SITL and is not run in CI (its flags and
missing-binary error are tested in test_demo_sitl_cli.py); its measured output is in docs/ardupilot.md.
"""

from __future__ import annotations

import json
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from demos import height_hold, wall_hover
from demos.controllers.height_hold import MAX_SPEED_M_S, VELOCITY_ONLY, Hold, Link, pymavlink_url
from demos.scoring import Window, height_metrics

M = mav.MAVLink(None, srcSystem=1, srcComponent=1)


def _parsed(msg: mav.MAVLink_message) -> mav.MAVLink_message:
    """``msg`` as the controller gets it: packed, then parsed by pymavlink from the bytes."""
    parser = mav.MAVLink(None)
    got = parser.parse_char(bytearray(msg.pack(M)))
    assert got is not None
    return got


def _ranging(sid: int, cm: int, quality: int = 0, lo: int = 20, hi: int = 4000) -> mav.MAVLink_message:
    return _parsed(mav.MAVLink_distance_sensor_message(1000, lo, hi, cm, 10, sid, 25, 0, signal_quality=quality))


def test_velocity_only_type_mask_keeps_vx_vy_vz_and_ignores_the_rest() -> None:
    velocity_bits = (
        mav.POSITION_TARGET_TYPEMASK_VX_IGNORE | mav.POSITION_TARGET_TYPEMASK_VY_IGNORE
        | mav.POSITION_TARGET_TYPEMASK_VZ_IGNORE
    )  # fmt: skip
    assert VELOCITY_ONLY & velocity_bits == 0
    assert VELOCITY_ONLY == 0b1101_1100_0111  # position, acceleration, yaw and yaw rate ignored (3527)


def test_mean_height_and_vertical_command() -> None:
    rule = Hold(target_m=5.0, gain=0.8)
    assert rule.height({}) is None
    assert rule.height({0: 5.0, 1: 5.2, 2: 5.4}) == pytest.approx(5.2)
    assert rule.down_m_s(None) == 0.0  # nothing to fly by: hold
    assert rule.down_m_s(5.5) == pytest.approx(0.4)  # too high: descend (NED down positive)
    assert rule.down_m_s(4.5) == pytest.approx(-0.4)  # too low: climb
    assert rule.down_m_s(50.0) == MAX_SPEED_M_S
    assert rule.down_m_s(math.nan) == 0.0


def test_hold_begins_after_one_second_on_target() -> None:
    rule = Hold(target_m=5.0)
    assert rule.settle(0.0, 3.0) is None
    assert rule.settle(1.0, 4.9) is None  # on target from here...
    assert rule.settle(1.5, 5.1) is None
    assert rule.settle(1.9, 5.3) is None  # ...off again: the second starts over
    assert rule.settle(2.0, 5.0) is None
    assert rule.settle(3.0, 5.05) is True
    assert rule.settle(3.1, 5.0) is None  # logged once


def test_hold_begins_anyway_after_the_approach_limit() -> None:
    rule = Hold(target_m=5.0)
    assert rule.settle(0.0, None) is None
    assert rule.settle(29.9, None) is None
    assert rule.settle(30.0, None) is False


def test_url_in_the_demos_mavsdk_form_is_given_to_pymavlink_in_its_own() -> None:
    assert pymavlink_url("udpin://127.0.0.1:14540") == "udpin:127.0.0.1:14540"
    assert pymavlink_url("tcp:127.0.0.1:5760") == "tcp:127.0.0.1:5760"


def test_link_reads_the_vehicle_and_the_rule_of_the_wall_controller() -> None:
    link = Link(conn=None)
    armed = mav.MAV_MODE_FLAG_SAFETY_ARMED
    link.take(_parsed(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, armed,
                                                    4, 4, 3)), 0.0)  # fmt: skip
    assert (link.sysid, link.compid, link.armed) == (1, 1, True)
    link.take(_ranging(0, 500), 0.0)  # ArduPilot's quality 0: a reading
    link.take(_ranging(1, 520, quality=1), 0.0)  # marked invalid by the secure stage
    link.take(_ranging(2, 0), 0.0)  # below min_distance: no reading
    link.take(_parsed(mav.MAVLink_global_position_int_message(0, 0, 0, 589000, 5012, 0, 0, 0, 0)), 0.0)
    readings, flagged = link.ranges.fresh(0.1, {0, 1, 2})
    assert readings == {0: 5.0}
    assert flagged == [1]
    assert link.relative_alt_m == pytest.approx(5.012)
    assert link.ranges.fresh(1.0, {0, 1, 2}) == ({}, [])  # older than 0.5 s: stale


def test_link_ignores_other_systems_once_it_knows_its_autopilot() -> None:
    link = Link(conn=None, sysid=1)
    other = mav.MAVLink(None, srcSystem=2, srcComponent=1)
    msg = mav.MAVLink_distance_sensor_message(1000, 20, 4000, 700, 10, 0, 25, 0)
    got = mav.MAVLink(None).parse_char(bytearray(msg.pack(other)))
    link.take(got, 0.0)
    assert link.ranges.by_id == {}


def test_height_score_from_truth_touching_ground_only_inside_the_window() -> None:
    window = Window(start_s=10.0, end_s=20.0, hold_s=5.0)
    truth = [(0.0, 0.0), (5.0, 5.0), (10.0, 5.0), (15.0, 4.0), (20.0, 3.0), (30.0, 0.0)]  # on the ground outside it
    steps = [{"wall_s": 12.0, "distance_m": 5.0, "flagged": [2]}, {"wall_s": 18.0, "distance_m": 5.0, "flagged": [2]}]
    estimates = [(12.0, {"attacked": [2], "step_time_s": 0.001}), (25.0, {"attacked": [0]})]
    f = height_metrics(truth, 5.0, steps, estimates, window)
    assert f["collided"] is False
    assert f["distance_error_m"]["samples"] == 3
    assert f["distance_error_m"]["max"] == pytest.approx(2.0)
    assert f["distance_error_m"]["rms"] == pytest.approx(math.sqrt((0 + 1 + 4) / 3), abs=1e-4)
    assert f["min_distance_m"] == 3.0
    assert f["seen_error_m"]["max"] == 0.0
    assert f["flagged_by_proxy"] == {"2": 1.0}
    assert f["flagged_by_controller_steps"] == {"2": 2}
    json.dumps(f)  # report.json takes it as it is
    touched = height_metrics([(12.0, 0.03)], 5.0, [], [], window)
    assert touched["collided"] is True
    assert height_hold.summary(f) == (
        "height error rms 1.29 m, max 2.00 m, min height 3.00 m, touched ground False, flagged by proxy {'2': 1.0}"
    )
    assert wall_hover.summary(f) == "distance error rms 1.29 m, max 2.00 m, min distance 3.00 m, collided False"

"""A wall group's readings projected on the wall's normal with ATTITUDE (mitm_proxy/stages/secure/tilt.py).

A multirotor pitches to move, and a forward beam then meets the wall at ``d / cos``: honest readings swing
while the distance does not. The projection is checked against flightsim's own ray casting and rotation
code, then on a pitching hover through the real stage: with it the honest group stays honest, without it
(``tilt: false``) the same stream has its honest sensors judged attacked.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from flightsim.control.rotation import quat_from_euler, rotate
from flightsim.world import World
from mitm_proxy.stages.secure.stage import FLAGGED_QUALITY, SecureConfig, SecureStage
from mitm_proxy.stages.secure.tilt import MIN_FACTOR, Geometry
from secuav_common.scenario import Scenario, load_scenario
from secuav_common.sensor_ids import MOUNT_BODY, ORIENTATION
from tests.support.secure_streams import StreamMaker, run

DS = 132
ANGLE = st.floats(-0.8, 0.8)  # rad, about 46 degrees


@pytest.fixture(scope="module")
def wall() -> Scenario:
    return load_scenario("wall_hover")


@settings(max_examples=200, deadline=None)
@given(roll=ANGLE, pitch=ANGLE, yaw=ANGLE, distance_m=st.floats(0.5, 20.0), height_m=st.floats(1.0, 10.0))
def test_a_tilted_beam_projected_is_the_distance_to_the_wall(
    wall: Scenario, roll: float, pitch: float, yaw: float, distance_m: float, height_m: float
) -> None:
    world = World(wall.world)
    plane = wall.wall("wall")
    normal = np.asarray(plane.normal_ned)
    pos = np.asarray(plane.point_ned_m) + distance_m * normal
    pos[2] = -height_m
    beam = rotate(quat_from_euler(roll, pitch, yaw), MOUNT_BODY["forward"])
    reading, hit = world.raycast(tuple(pos), beam)
    assume(hit == "wall")  # pitched down far enough, the beam meets the ground first
    factor = Geometry.of([ORIENTATION["forward"]], tuple(normal)).factors(roll, pitch, yaw)[0]  # type: ignore[union-attr]
    if math.isnan(factor):  # more than 60 degrees off the normal
        assert math.cos(pitch) * math.cos(yaw) < MIN_FACTOR + 1e-9 or distance_m / reading < MIN_FACTOR
    else:
        assert reading * factor == pytest.approx(distance_m, rel=1e-9)


@settings(max_examples=100, deadline=None)
@given(roll=ANGLE, pitch=ANGLE, yaw=st.floats(-math.pi, math.pi), height_m=st.floats(0.2, 30.0))
def test_a_tilted_downward_beam_projected_is_the_height_over_ground(
    wall: Scenario, roll: float, pitch: float, yaw: float, height_m: float
) -> None:
    beam = rotate(quat_from_euler(roll, pitch, yaw), MOUNT_BODY["down"])
    reading, hit = World(wall.world).raycast((0.0, 0.0, -height_m), beam)
    assume(hit == "ground")
    factor = Geometry.of([ORIENTATION["down"]], (0.0, 0.0, -1.0)).factors(roll, pitch, yaw)[0]  # type: ignore[union-attr]
    if math.isnan(factor):  # more than 60 degrees off the vertical
        assert math.cos(roll) * math.cos(pitch) < MIN_FACTOR
    else:
        assert reading * factor == pytest.approx(height_m, rel=1e-9)


def test_a_beam_far_off_the_normal_counts_as_missing() -> None:
    geometry = Geometry.of([ORIENTATION["forward"], ORIENTATION["right"]], (-1.0, 0.0, 0.0))
    assert geometry is not None
    level = geometry.factors(0.0, 0.0, 0.0)
    assert level[0] == pytest.approx(1.0) and math.isnan(level[1])  # the right-facing beam runs along the wall
    assert math.isnan(geometry.factors(0.0, 0.0, math.radians(61))[0])
    assert geometry.factors(0.0, 0.0, math.radians(59))[0] == pytest.approx(math.cos(math.radians(59)))


def pitching(t_s: float) -> tuple[float, float, float]:
    """The wall demo's approach, 5 m out: pitch swinging +-20 degrees at 1.5 Hz, a little roll and yaw."""
    return 0.05 * math.sin(2.0 * t_s), math.radians(20.0) * math.sin(2 * math.pi * 1.5 * t_s), 0.03


@pytest.mark.parametrize("tilt", [True, False])
def test_a_pitching_hover_keeps_its_honest_sensors_honest_only_with_the_projection(
    wall: Scenario, tilt: bool
) -> None:
    stage = SecureStage(SecureConfig(estimator="secekf", executor="inline", tilt=tilt), wall, 1)
    maker = StreamMaker(wall, seed=4, attitude=pitching)
    plane = wall.wall("wall")
    maker.hold = np.asarray(plane.point_ned_m) + 5.0 * np.asarray(plane.normal_ned)  # where the approach starts
    maker.hold[2] = -2.5
    outs = [o for o in run(stage, maker, 12.0) if o.msgid == DS and o.frame.clean["id"] in (0, 1, 2, 3, 4)]
    late = outs[len(outs) // 4 :]
    flagged = np.mean([o.fields["signal_quality"] == FLAGGED_QUALITY for o in late])
    if not tilt:
        assert flagged > 0.2, flagged  # what the stage did before: 43 % of honest readings judged attacked
        return
    assert flagged < 0.03, flagged
    # Each substituted reading is the range along its own tilted beam: what an honest sensor reads now.
    errors = [abs(o.fields["current_distance"] / 100.0 - o.frame.truth["range_m"]) for o in late]
    assert np.median(errors) < 0.03 and max(errors) < 0.2

"""Range sensors follow the geometry: rays against walls and ground, 3-D anchor and peer distances."""

from __future__ import annotations

import math
import random
import statistics

from hypothesis import given
from hypothesis import strategies as st

from flightsim.api import State
from flightsim.control.rotation import quat_from_euler, rotate
from flightsim.sensors import MOUNT_BODY, PeerRangeModel, RangefinderModel, UwbModel
from flightsim.world import GROUND, Plane, World
from secuav_common import scenario as sc

finite = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


def _unit(v: tuple[float, float, float]) -> tuple[float, float, float]:
    n = math.sqrt(sum(c * c for c in v))
    return (v[0] / n, v[1] / n, v[2] / n)


vectors = st.tuples(finite, finite, finite).filter(lambda v: math.sqrt(sum(c * c for c in v)) > 1e-3).map(_unit)


def _state(pos: tuple[float, float, float], roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> State:
    return State(
        0.0,
        pos,
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        quat_from_euler(roll, pitch, yaw),
        (roll, pitch, yaw),
        (0.0, 0.0, 0.0),
    )


@given(
    point=st.tuples(finite, finite, finite), normal=vectors, origin=st.tuples(finite, finite, finite), direction=vectors
)
def test_ray_hits_land_on_the_plane_from_its_free_side(point, normal, origin, direction) -> None:  # type: ignore[no-untyped-def]
    plane = Plane("p", point, normal)
    t = plane.ray_hit(origin, direction)
    facing = sum(n * d for n, d in zip(normal, direction, strict=True))
    if plane.signed_distance(origin) < 0 or facing >= -1e-12:
        assert t == math.inf
        return
    assert t >= 0
    if math.isfinite(t) and t < 1e6:
        hit = tuple(o + t * d for o, d in zip(origin, direction, strict=True))
        assert abs(plane.signed_distance(hit)) < 1e-6 * max(1.0, t)


@given(h=st.floats(0.1, 30), roll=st.floats(-1.2, 1.2), pitch=st.floats(-1.2, 1.2), yaw=angle)
def test_downward_ray_to_ground_scales_with_tilt(h: float, roll: float, pitch: float, yaw: float) -> None:
    q = quat_from_euler(roll, pitch, yaw)
    down = rotate(q, MOUNT_BODY["down"])
    # The body z axis makes cos(tilt) = cos(roll) cos(pitch) with the vertical.
    expected = h / (math.cos(roll) * math.cos(pitch))
    assert math.isclose(GROUND.ray_hit((1.0, 2.0, -h), down), expected, rel_tol=1e-9)


def _wall_world() -> World:
    return World(sc.World(walls=[sc.Wall(name="wall", point_ned_m=(5.0, 0.0, 0.0), normal_ned=(-1.0, 0.0, 0.0))]))


def test_forward_laser_sees_the_wall_through_a_pitched_vehicle() -> None:
    world = _wall_world()
    cfg = sc.Rangefinder(id=0, orientation="forward", noise_std_m=0.0, max_m=40)
    rf = RangefinderModel(cfg, world, random.Random(1))
    for pitch_deg in (0.0, 10.0, -15.0, 30.0):
        pitch = math.radians(pitch_deg)
        s = _state((2.0, 0.0, -2.5), pitch=pitch)
        to_wall = 3.0 / math.cos(pitch)
        # Nose down far enough and the beam hits the ground first.
        to_ground = 2.5 / math.sin(-pitch) if pitch < 0 else math.inf
        assert math.isclose(rf.true_distance(s), min(to_wall, to_ground), rel_tol=1e-9)
    # Rolled and yawed: the beam leaves the wall's normal sideways.
    s = _state((2.0, 0.0, -2.5), roll=0.3, yaw=math.radians(20))
    assert math.isclose(rf.true_distance(s), 3.0 / math.cos(math.radians(20)), rel_tol=1e-9)
    # Facing away: nothing but the horizon.
    assert rf.true_distance(_state((2.0, 0.0, -2.5), yaw=math.pi)) == math.inf


def test_rangefinder_noise_rate_limits_and_dropout() -> None:
    world = _wall_world()
    cfg = sc.Rangefinder(
        id=3, type="infrared", orientation="forward", min_m=0.1, max_m=8, noise_std_m=0.04, rate_hz=20, dropout_prob=0.2
    )
    rf = RangefinderModel(cfg, world, random.Random(7))
    readings = []
    for k in range(250 * 50):  # 50 s of physics steps at 250 Hz
        s = State(k / 250, (2.5, 0.0, -2.5), (0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, (0.0,) * 3)
        r = rf.sample(s)
        if r is not None:
            readings.append(r)
    assert len(readings) == 1000  # 20 Hz for 50 s
    assert readings[0].sensor_id == 3 and readings[0].sensor_type == 2 and readings[0].orientation == 0
    values = [r.distance_m for r in readings]
    valid = [d for d in values if not math.isnan(d)]
    assert 0.15 < 1 - len(valid) / len(values) < 0.25
    assert abs(statistics.fmean(valid) - 2.5) < 4 * 0.04 / math.sqrt(len(valid))
    assert 0.035 < statistics.stdev(valid) < 0.045
    # Beyond max_m: no target, NaN.
    far = State(60.0, (-10.0, 0.0, -2.5), (0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, (0.0,) * 3)
    assert math.isnan(rf.sample(far).distance_m)  # type: ignore[union-attr]


def test_uwb_ranges_go_out_as_10_plus_anchor_id_with_3d_distance() -> None:
    anchors = {0: (0.0, 0.0, -1.0), 3: (5.0, 2.5, -1.0), 7: (0.0, 2.5, -1.0)}
    uwb = UwbModel(sc.UwbRanging(noise_std_m=0.0, rate_hz=10), anchors, random.Random(0))
    s = _state((2.5, 2.5, -2.5))
    out = uwb.sample(s)
    assert [r.sensor_id for r in out] == [10, 13, 17]
    for r, a in zip(out, anchors.values(), strict=True):
        assert math.isclose(r.distance_m, math.dist(s.pos_ned_m, a), rel_tol=1e-12)
        assert r.orientation == 100 and r.sensor_type == 4
    assert uwb.sample(_state((2.5, 2.5, -2.5))) == []  # t = 0 again: not due


def test_peer_ranges_go_out_as_50_plus_sysid() -> None:
    model = PeerRangeModel(sc.InterVehicleRanging(peers=[2, 7], noise_std_m=0.0), random.Random(0))
    me = _state((4.0, 4.0, -2.5))
    out = model.sample(me, {2: _state((1.0, 0.0, -2.5)), 7: _state((4.0, 4.0, -4.5))})
    assert [(r.sensor_id, r.distance_m) for r in out] == [(52, 5.0), (57, 2.0)]


def test_collision_rules_of_the_world() -> None:
    world = _wall_world()
    level, upside_down, tipped = 1.0, math.cos(math.radians(120)), math.cos(math.radians(70))
    still = (0.0, 0.0, 0.0)
    assert world.check_collision((2.0, 0.0, -2.0), still, level, False) is None
    hit = world.check_collision((4.8, 0.0, -2.0), (1.8, 0.0, 0.0), level, False)
    assert hit is not None and hit.text == "collision with wall 'wall' at 1.8 m/s"
    assert world.check_collision((1.0, 0.0, 0.0), (0.0, 0.0, 1.5), level, True) is None  # firm landing
    hard = world.check_collision((1.0, 0.0, 0.0), (0.0, 0.0, 3.1), level, True)
    assert hard is not None and hard.text == "collision with the ground at 3.1 m/s"
    assert world.check_collision((1.0, 0.0, -2.0), still, upside_down, False).what == "flip"  # type: ignore[union-attr]
    assert world.check_collision((1.0, 0.0, -2.0), still, tipped, False) is None  # steep, but flying
    assert world.check_collision((1.0, 0.0, 0.0), still, tipped, True).what == "flip"  # type: ignore[union-attr]
    assert World.vehicles_touch((0.0, 0.0, -2.0), (0.0, 0.45, -2.0))
    assert not World.vehicles_touch((0.0, 0.0, -2.0), (0.0, 0.55, -2.0))

"""The autopilot's fusion of a companion's readings (flightsim/external.py), without a network.

Each test gives :class:`ExternalFusion` readings and a base estimate and checks the fused position against
the geometry worked by hand; the last ones go through the PX4 personality with real frames.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from flightsim.api import ExternalPosition, ExternalRange, State
from flightsim.control.rotation import quat_from_euler
from flightsim.external import ExternalFusion, multilaterate
from flightsim.mavlink import Px4Personality
from flightsim.mavlink.wire import Encoder
from flightsim.simulation import Simulation
from flightsim.world import GROUND, Plane
from secuav_common.scenario import load_scenario, parse_scenario

DOWN, FORWARD, CUSTOM = 25, 0, 100
WALL = Plane("wall", (6.0, 0.0, 0.0), (-1.0, 0.0, 0.0))
DT = 0.02


def base(pos=(0.0, 0.0, -5.0), vel=(0.0, 0.0, 0.0), t=0.0, pitch=0.0) -> State:
    q = quat_from_euler(0.0, pitch, 0.0)
    return State(t, pos, vel, (0.0, 0.0, 0.0), q, (0.0, pitch, 0.0), (0.0, 0.0, 0.0))


def fusion(external: str, anchors: str = "") -> ExternalFusion:
    text = f"name: t\nworld: {{walls: [{{name: wall, point_ned_m: [6, 0, 0], normal_ned: [-1, 0, 0]}}]{anchors}}}\n"
    text += f"vehicles: [{{sysid: 1, external: {external}}}]"
    sc = parse_scenario(text)
    ext = sc.vehicles[0].external
    assert ext is not None
    return ExternalFusion(ext, 1, {"wall": WALL, "ground": GROUND}, sc.anchor_positions())


RANGES = "{rangefinders: [{id: 0, orientation: down}, {id: 1, orientation: forward, surface: wall}]}"


def fly(f: ExternalFusion, seconds: float, reading: dict[int, float], est: State, t0: float = 0.0) -> State:
    """Tick at 50 Hz, a reading of each id every other tick (25 Hz); the last fused state."""
    out = est
    for k in range(round(seconds / DT)):
        t = t0 + k * DT
        if k % 2 == 0:
            for sid, d in reading.items():
                f.take_range(ExternalRange(1, 158, sid, d, DOWN if sid == 0 else FORWARD), t)
        out = f.fuse(base(est.pos_ned_m, est.vel_ned_m_s, t, est.euler_rad[1]), DT)
    return out


def test_a_downward_reading_sets_the_height_and_a_wall_reading_the_distance() -> None:
    f = fusion(RANGES)
    est = fly(f, 2.0, {0: 7.0, 1: 2.0}, base(pos=(0.5, 0.3, -5.0)))
    n, e, d = est.pos_ned_m
    assert d == pytest.approx(-7.0, abs=1e-6)  # the ground's normal: height = the reading
    assert n == pytest.approx(6.0 - 2.0, abs=1e-6)  # the wall's normal: 2 m short of the wall at 6 m
    assert e == pytest.approx(0.3)  # along no normal: the base estimate's
    assert f.sources_in_use() == ["rangefinder 0", "rangefinder 1"]


def test_a_tilted_beam_is_projected_on_the_normal() -> None:
    f = fusion(RANGES)
    pitch = math.radians(20)  # nose up: the downward beam leans back, reading h / cos(pitch)
    est = fly(f, 2.0, {0: 5.0 / math.cos(pitch)}, base(pitch=pitch))
    assert est.pos_ned_m[2] == pytest.approx(-5.0, abs=1e-6)


def test_between_readings_the_estimate_moves_with_the_velocity_and_a_step_is_followed_within_a_second() -> None:
    f = fusion(RANGES)
    fly(f, 1.0, {0: 5.0}, base())
    est = fly(f, 1.0, {0: 7.0}, base(), t0=1.0)  # a 2 m lie starts
    assert est.pos_ned_m[2] == pytest.approx(-7.0, abs=0.01)
    half = fly(f, 0.1, {0: 5.0}, base(), t0=2.0)  # back to the truth: 0.1 s is 3 readings of gain 0.2
    assert -7.0 < half.pos_ned_m[2] + 0.5 < -5.0


def test_a_source_that_stops_is_dropped_with_a_warning_and_taken_again_when_it_returns() -> None:
    f = fusion(RANGES)
    fly(f, 1.0, {0: 7.0}, base())
    assert f.pop_status() == [(6, "External rangefinder 0 in use")]
    quiet = fly(f, 1.0, {}, base(), t0=1.0)
    assert quiet.pos_ned_m[2] == -5.0  # the own estimate again
    assert f.pop_status() == [(4, "External rangefinder 0 lost for 0.5 s: using own estimate")]
    back = fly(f, 0.1, {0: 6.0}, base(), t0=2.0)
    assert back.pos_ned_m[2] == pytest.approx(-6.0)  # restarted from the reading, not from the stale 7 m
    assert f.pop_status() == [(6, "External rangefinder 0 in use")]
    assert f.stats.dropouts == 1


def test_readings_the_vehicle_does_not_expect_are_ignored() -> None:
    f = fusion(RANGES)
    assert not f.take_range(ExternalRange(1, 190, 0, 7.0, DOWN), 0.0)  # a ground station's compid
    assert not f.take_range(ExternalRange(2, 158, 0, 7.0, DOWN), 0.0)  # another system
    assert not f.take_range(ExternalRange(1, 158, 5, 7.0, DOWN), 0.0)  # an undeclared id
    assert not f.take_range(ExternalRange(1, 158, 0, 7.0, FORWARD), 0.0)  # facing the wrong way
    assert not f.take_position(ExternalPosition(1, 158, (1.0, 2.0, 3.0), "odometry"), 0.0)  # no vision declared
    assert f.stats.ignored == 5 and f.stats.taken == 0
    assert f.fuse(base(), DT).pos_ned_m == (0.0, 0.0, -5.0)


def test_out_of_range_is_no_target_but_still_re_reported() -> None:
    f = fusion(RANGES)
    assert f.take_range(ExternalRange(1, 158, 0, 41.0, DOWN), 0.0)  # beyond max_m 40
    assert f.take_range(ExternalRange(1, 158, 0, math.nan, DOWN), 0.0)
    assert f.stats.invalid == 2 and f.stats.taken == 0
    reports = f.pop_reports()
    assert [r.sensor_id for r in reports] == [0, 0] and all(math.isnan(r.distance_m) for r in reports)
    assert f.fuse(base(), DT).pos_ned_m == (0.0, 0.0, -5.0)


def test_vision_sets_the_position_and_a_downward_laser_still_the_height() -> None:
    f = fusion("{vision: true, source_compids: [197], rangefinders: [{id: 0, orientation: down}]}")
    est = base()
    for k in range(50):
        f.take_position(ExternalPosition(1, 197, (1.0, 2.0, -4.0), "vision_position_estimate"), k * DT)
        if k % 2 == 0:
            f.take_range(ExternalRange(1, 197, 0, 3.0, DOWN), k * DT)
        est = f.fuse(base(t=k * DT), DT)
    n, e, d = est.pos_ned_m
    assert (n, e) == (pytest.approx(1.0, abs=1e-3), pytest.approx(2.0, abs=1e-3))
    assert d == pytest.approx(-3.0, abs=1e-6)


ANCHORS = ", anchors: [{id: 0, pos_ned_m: [0, 0, -1]}, {id: 1, pos_ned_m: [5, 0, 0]}, " \
          "{id: 2, pos_ned_m: [5, 5, -2]}, {id: 3, pos_ned_m: [0, 5, 0]}, {id: 4, pos_ned_m: [2.5, 2.5, -6]}]"


def test_uwb_ranges_give_a_least_squares_fix() -> None:
    f = fusion("{uwb: {noise_std_m: 0.1}}", ANCHORS)
    truth = (1.0, 3.0, -2.5)
    est = base(pos=(2.0, 2.0, -2.0))
    for k in range(50):
        for sid, a in f.anchors.items():
            f.take_range(ExternalRange(1, 158, sid, math.dist(truth, a), CUSTOM), k * DT)
        est = f.fuse(base(pos=(2.0, 2.0, -2.0), t=k * DT), DT)
    assert est.pos_ned_m == pytest.approx(truth, abs=1e-4)
    assert f.sources_in_use() == ["UWB position"]


def test_multilateration_refuses_a_flat_singular_geometry() -> None:
    line = [((float(k), 0.0, 0.0), 1.0) for k in range(4)]  # all anchors on one line: rank 1
    assert multilaterate((0.5, 1.0, 0.0), line) is None


def test_the_personality_hands_a_companions_frames_to_the_estimator_and_ignores_a_gcs() -> None:
    sim = Simulation(load_scenario("companion_feed"))
    v = sim.vehicles[1]
    out: list[bytes] = []
    p = Px4Personality(v, out.append)
    companion, gcs = Encoder(1, 158), Encoder(255, 190)
    frame = companion.mav.distance_sensor_encode(0, 5, 4000, 700, 0, 0, DOWN, 0)
    p.receive(companion.pack(frame), 0.0)
    p.receive(gcs.pack(gcs.mav.distance_sensor_encode(0, 5, 4000, 900, 0, 0, DOWN, 0)), 0.0)
    vis = companion.mav.vision_position_estimate_encode(0, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0)
    p.receive(companion.pack(vis), 0.0)  # this scenario declares no vision
    assert (p.stats.external_taken, p.stats.external_ignored) == (1, 2)
    sim.run_for(0.1)
    assert v.estimate.pos_ned_m[2] == pytest.approx(-7.0, abs=0.05)  # 7.00 m below, as the companion said
    body = companion.mav.odometry_encode(0, mavlink.MAV_FRAME_BODY_FRD, 0, 1.0, 2.0, -3.0, [1, 0, 0, 0],
                                         0, 0, 0, 0, 0, 0, [math.nan] * 21, [math.nan] * 21)  # fmt: skip
    p.receive(companion.pack(body), 0.0)  # a body-frame position is not a map position: not read
    assert p.stats.external_ignored == 3


UWB_WORLD = """world:
  anchors: [{id: 0, pos_ned_m: [-4, -4, -0.5]}, {id: 1, pos_ned_m: [4, -4, -5]}, {id: 2, pos_ned_m: [4, 4, -0.5]},
            {id: 3, pos_ned_m: [-4, 4, -5]}, {id: 4, pos_ned_m: [0, 0, -8]}, {id: 5, pos_ned_m: [0, 6, -2]}]
"""
CLOSED_LOOP = {
    "vision": ("name: t\nvehicles: [{sysid: 1, external: {vision: {rate_hz: 25}}}]", ["vision"], "vision"),
    "odometry": ("name: t\nvehicles: [{sysid: 1, external: {vision: {message: odometry}}}]", ["odometry"], "vision"),
    "uwb": ("name: t\n" + UWB_WORLD + "vehicles: [{sysid: 1, external: {uwb: {noise_std_m: 0.05, rate_hz: 10}}}]",
            ["uwb"], "UWB position"),
}


@pytest.mark.parametrize("kind", list(CLOSED_LOOP))
def test_in_closed_loop_a_shifted_feed_moves_the_vehicle_and_its_loss_brings_it_back(kind: str) -> None:
    """Headless: the feed's own builder, frames through the personality, 50 Hz like the runner; truth scores.

    Bounds: the hold errs by a few centimetres and the fused position by the feed's noise smoothed (2-5 cm
    per axis), so 0.2 m while truthful and 0.3 m around the 1.5 m shift leave a wide margin; the 6 s given
    to each move is three times what a 1.5 m leg at the hold's speed takes."""
    from dataclasses import replace

    from flightsim.companion.feed import FeedBuilder

    text, sensors, name = CLOSED_LOOP[kind]
    sc = parse_scenario(text)
    sim = Simulation(sc)
    v = sim.vehicles[1]
    p = Px4Personality(v, lambda _: None)
    sim.take_off(3.0)
    enc = Encoder(1, 158)
    feed = FeedBuilder(sc, 1, sensors, enc.mav)

    def fly(seconds: float, shift_north_m: float | None) -> float:
        for _ in range(round(seconds / 0.02)):
            sim.run_for(0.02)
            if shift_north_m is not None:
                t = v.truth
                lie = replace(t, pos_ned_m=(t.pos_ned_m[0] + shift_north_m, *t.pos_ned_m[1:]))
                p.receive(b"".join(enc.pack(m) for m in feed.messages(lie)), 0.0)
        return v.truth.pos_ned_m[0]

    start = v.truth.pos_ned_m[0]
    assert abs(fly(4.0, 0.0) - start) < 0.2  # the truthful feed holds where GPS held
    texts = [t for _, t in v.pop_status_texts()]
    assert f"External {name} in use" in texts
    assert abs(fly(6.0, 1.5) - (start - 1.5)) < 0.3  # it believes the feed: 1.5 m north of truth is "here"
    back = fly(6.0, None)  # the feed stops: GPS again, and the vehicle flies back to its hold point
    assert abs(back - start) < 0.3
    assert f"External {name} lost for 0.5 s: using own estimate" in [t for _, t in v.pop_status_texts()]
    assert p.stats.external_taken > 200 and p.stats.external_ignored == 0


FUZZ_SCENARIO = parse_scenario("name: fuzz\n" + UWB_WORLD + "vehicles: [{sysid: 1, external: {vision: true, "
                               "uwb: {}, rangefinders: [{id: 0, orientation: down}]}}]")


@settings(max_examples=50, deadline=None)  # each example builds a JSBSim vehicle
@given(
    st.lists(
        st.one_of(
            st.tuples(st.just("range"), st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF),
                      st.sampled_from([0, 25, 100, 7])),
            st.tuples(st.just("vision"), st.floats(width=32), st.floats(width=32), st.floats(width=32)),
        ),
        max_size=20,
    )
)  # fmt: skip
def test_any_companion_frame_leaves_a_finite_estimate(frames: list[tuple]) -> None:
    """Whatever a companion sends (ids, distances, limits, NaN, infinities, 1e38), nothing raises and the
    estimate stays a number: an attacker can move the vehicle, not break its arithmetic."""
    sim = Simulation(FUZZ_SCENARIO)
    v = sim.vehicles[1]
    p = Px4Personality(v, lambda _: None)
    enc = Encoder(1, 158)
    for f in frames:
        if f[0] == "range":
            _, sid, cm, max_cm, facing = f
            msg = enc.mav.distance_sensor_encode(0, 1, max_cm, cm, 0, sid, facing, 0)
        else:
            msg = enc.mav.vision_position_estimate_encode(0, f[1], f[2], f[3], 0.0, 0.0, 0.0)
        p.receive(enc.pack(msg), 0.0)
        sim.run_for(0.02)
    assert p.stats.external_taken + p.stats.external_ignored == len(frames)
    assert all(math.isfinite(c) for c in v.estimate.pos_ned_m)

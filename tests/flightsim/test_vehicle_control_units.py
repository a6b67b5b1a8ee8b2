"""Pure parts of the autopilot: mixer allocation, attitude construction, rotations."""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st

from flightsim.control.mixer import MOTOR_SPIN, MOTOR_X, MOTOR_Y, MotorModel, XQuadMixer
from flightsim.control.position import GRAVITY_M_S2, PositionController, Setpoint
from flightsim.control.rotation import (
    euler_from_quat,
    quat_from_body_z_and_yaw,
    quat_from_euler,
    rotate,
    rotate_inverse,
)
from flightsim.navigator import Carrot

small_torque = st.floats(-0.05, 0.05)
angle = st.floats(-math.pi + 1e-6, math.pi - 1e-6)


def _wrench(mixer: XQuadMixer, cmds: tuple[float, ...]) -> tuple[float, float, float, float]:
    f = [mixer.motor.force_n(c) for c in cmds]
    thrust = sum(f)
    tx = sum(-MOTOR_Y[i] * f[i] for i in range(4))
    ty = sum(MOTOR_X[i] * f[i] for i in range(4))
    tz = sum(mixer.motor.yaw_moment_m * MOTOR_SPIN[i] * f[i] for i in range(4))
    return thrust, tx, ty, tz


@given(thrust=st.floats(8.0, 30.0), tx=small_torque, ty=small_torque, tz=st.floats(-0.02, 0.02))
def test_mixer_produces_the_asked_wrench_when_unsaturated(thrust: float, tx: float, ty: float, tz: float) -> None:
    mixer = XQuadMixer()
    cmds = mixer.mix(thrust, (tx, ty, tz))
    if mixer.saturated:
        return
    got = _wrench(mixer, cmds)
    assert math.isclose(got[0], thrust, rel_tol=1e-9)
    for want, have in zip((tx, ty, tz), got[1:], strict=True):
        assert abs(want - have) < 1e-9


def test_mixer_keeps_roll_over_yaw_when_saturated() -> None:
    mixer = XQuadMixer()
    cmds = mixer.mix(13.7, (0.3, 0.0, 0.5))
    assert mixer.saturated
    assert all(mixer.motor.idle_cmd - 1e-9 <= c <= 1.0 + 1e-9 for c in cmds)
    _, tx, _, tz = _wrench(mixer, cmds)
    assert math.isclose(tx, 0.3, rel_tol=1e-6)  # roll fully delivered
    assert 0 <= tz < 0.5  # yaw only with the headroom left


def test_motor_model_inverts() -> None:
    m = MotorModel()
    for c in (0.0, 0.1, 0.42, 0.9, 1.0):
        assert math.isclose(m.cmd_for(m.force_n(c)), c, abs_tol=1e-12)


@given(roll=st.floats(-1.4, 1.4), pitch=st.floats(-1.4, 1.4), yaw=angle)
def test_euler_quaternion_round_trip_and_rotation_inverse(roll: float, pitch: float, yaw: float) -> None:
    q = quat_from_euler(roll, pitch, yaw)
    r, p, y = euler_from_quat(q)
    assert math.isclose(r, roll, abs_tol=1e-9) and math.isclose(p, pitch, abs_tol=1e-9)
    assert math.isclose(math.remainder(y - yaw, 2 * math.pi), 0.0, abs_tol=1e-9)
    v = (0.3, -1.2, 2.0)
    back = rotate_inverse(q, rotate(q, v))
    assert all(math.isclose(a, b, abs_tol=1e-12) for a, b in zip(v, back, strict=True))
    # Forward axis after yaw only points along the heading.
    fwd = rotate(quat_from_euler(0.0, 0.0, yaw), (1.0, 0.0, 0.0))
    assert math.isclose(fwd[0], math.cos(yaw), abs_tol=1e-12) and math.isclose(fwd[1], math.sin(yaw), abs_tol=1e-12)


@given(zx=st.floats(-0.5, 0.5), zy=st.floats(-0.5, 0.5), yaw=angle)
def test_attitude_from_thrust_direction_and_heading(zx: float, zy: float, yaw: float) -> None:
    n = math.sqrt(zx * zx + zy * zy + 1.0)
    body_z = (zx / n, zy / n, 1.0 / n)
    q = quat_from_body_z_and_yaw(body_z, yaw)
    got_z = rotate(q, (0.0, 0.0, 1.0))
    assert all(math.isclose(a, b, abs_tol=1e-9) for a, b in zip(got_z, body_z, strict=True))
    # The body x axis, projected on the ground, points along the heading.
    x = rotate(q, (1.0, 0.0, 0.0))
    assert abs(math.remainder(math.atan2(x[1], x[0]) - yaw, 2 * math.pi)) < 1e-9


def test_position_controller_hover_thrust_and_tilt_limit() -> None:
    pc = PositionController(mass_kg=1.4)
    level = quat_from_euler(0.0, 0.0, 0.0)
    hover = pc.update(Setpoint(pos_ned_m=(0.0, 0.0, -2.0)), (0.0, 0.0, -2.0), (0.0, 0.0, 0.0), 0.0, level, 0.02)
    assert math.isclose(hover.thrust_n, 1.4 * GRAVITY_M_S2, rel_tol=1e-9)
    far = pc.update(Setpoint(pos_ned_m=(100.0, 0.0, -2.0)), (0.0, 0.0, -2.0), (0.0, 0.0, 0.0), 0.0, level, 0.02)
    tilt = math.acos(rotate(far.quat, (0.0, 0.0, 1.0))[2])
    assert math.isclose(tilt, pc.limits.tilt_max_rad, rel_tol=1e-6)
    assert rotate(far.quat, (1.0, 0.0, 0.0))[2] > 0  # nose down (x axis below the horizon) to go north


@given(
    target=st.tuples(st.floats(-15, 15), st.floats(-15, 15), st.floats(-15, 0)),
    cap=st.floats(2.0, 8.0),
    acc=st.floats(1.0, 5.0),
)
@example(target=(0.0, 2.5932444843689858e-06, 0.0), cap=2.0, acc=5.0)  # micrometres away: one step would pass it
@settings(max_examples=30, deadline=None)
def test_carrot_reaches_any_target_within_its_limits_without_overshoot(
    target: tuple[float, float, float], cap: float, acc: float
) -> None:
    start = (0.0, 0.0, -2.0)
    carrot = Carrot()
    carrot.reset(start, (0.0, 0.0, 0.0))
    dt = 0.02
    dxy = math.dist(start[:2], target[:2])
    ux, uy = ((target[0] - start[0]) / dxy, (target[1] - start[1]) / dxy) if dxy > 0 else (0.0, 0.0)
    for _ in range(1500):  # 30 s: enough for 26 m at the slowest limits
        carrot.advance(target, cap, cap, cap, acc, acc, dt)
        (x, y, z), (vx, vy, vz), (ax, ay, az) = carrot.pos, carrot.vel, carrot.acc
        # Never faster than the cap; acceleration within the limit except for the raw carrot's
        # last braking steps and snap onto the target, which the smoothing keeps under 1.5 acc ...
        assert math.hypot(vx, vy) <= cap * 1.01 + 1e-9 and abs(vz) <= cap * 1.01 + 1e-9
        assert math.hypot(ax, ay) <= acc * 1.5 + 1e-9 and abs(az) <= acc * 1.5 + 1e-9
        # ... and never past the target along the way there.
        assert (x - start[0]) * ux + (y - start[1]) * uy <= dxy + 1e-6
        assert min(start[2], target[2]) - 1e-6 <= z <= max(start[2], target[2]) + 1e-6
        if math.dist(carrot.pos, target) < 1e-3 and math.hypot(vx, vy, vz) < 1e-3:
            break
    else:
        raise AssertionError(f"carrot still {math.dist(carrot.pos, target):.3f} m from the target")

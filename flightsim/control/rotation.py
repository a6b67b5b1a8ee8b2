"""Small 3-D rotation helpers on plain tuples.

Quaternions are ``(w, x, y, z)`` and rotate body vectors into NED (the
convention of :mod:`flightsim.api`). Plain floats instead of numpy because the
inner loops run 200 times per simulated second per vehicle and numpy's
per-call overhead on 3-vectors would dominate.
"""

from __future__ import annotations

import math

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """Quaternion of the aerospace ZYX sequence (yaw, then pitch, then roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q: Quat) -> Vec3:
    """(roll, pitch, yaw) in radians of a body -> NED quaternion."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def quat_mul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: Quat) -> Quat:
    return q[0], -q[1], -q[2], -q[3]


def rotate(q: Quat, v: Vec3) -> Vec3:
    """Rotate body vector ``v`` into NED with body -> NED quaternion ``q``."""
    w, x, y, z = q
    vx, vy, vz = v
    # v' = v + 2w (u x v) + 2 u x (u x v), u = (x, y, z)
    tx = 2 * (y * vz - z * vy)
    ty = 2 * (z * vx - x * vz)
    tz = 2 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def rotate_inverse(q: Quat, v: Vec3) -> Vec3:
    """Rotate NED vector ``v`` into the body frame."""
    return rotate(quat_conj(q), v)


def quat_from_body_z_and_yaw(body_z_ned: Vec3, yaw: float) -> Quat:
    """Attitude whose body z axis is ``body_z_ned`` (unit) and whose heading is ``yaw``.

    The thrust direction fixes two degrees of freedom, the yaw the third; this is
    how a multirotor position controller turns an acceleration into an attitude.
    """
    zx, zy, zz = body_z_ned
    # An axis in the horizontal plane, perpendicular to the desired heading.
    yc = (-math.sin(yaw), math.cos(yaw), 0.0)
    # body x = yc cross body z
    xx = yc[1] * zz - yc[2] * zy
    xy = yc[2] * zx - yc[0] * zz
    xz = yc[0] * zy - yc[1] * zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    if n < 1e-9:  # thrust horizontal: undefined heading, keep any orthogonal axis
        xx, xy, xz, n = 1.0, 0.0, 0.0, 1.0
    xx, xy, xz = xx / n, xy / n, xz / n
    # body y = body z cross body x
    yx = zy * xz - zz * xy
    yy = zz * xx - zx * xz
    yz = zx * xy - zy * xx
    return quat_from_matrix(((xx, yx, zx), (xy, yy, zy), (xz, yz, zz)))


def quat_from_matrix(m: tuple[Vec3, Vec3, Vec3]) -> Quat:
    """Quaternion of a rotation matrix given row by row (columns = body axes in NED)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 > m11 and m00 > m22:
        s = math.sqrt(1.0 + m00 - m11 - m22) * 2
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 > m22:
        s = math.sqrt(1.0 + m11 - m00 - m22) * 2
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = math.sqrt(1.0 + m22 - m00 - m11) * 2
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    return q if q[0] >= 0 else (-q[0], -q[1], -q[2], -q[3])


def wrap_pi(angle: float) -> float:
    """Angle in radians mapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi

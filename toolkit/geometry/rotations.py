"""Every rotation of the toolkit, vectorised: Z-Y-X Euler angles, matrices, quaternions.

Attitude is Z-Y-X Euler (roll, pitch, yaw): ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` maps
base_link vectors into ENU (world from body). Quaternions are (x, y, z, w), as ROS 2 and
Foxglove write them. The pose filter works on stacked arrays (``(..., 3)``); ingest and the
Foxglove view on one column per component.
"""

from __future__ import annotations

import math

import numpy as np

from toolkit.arrays import FloatArray


def wrap_angle(a: FloatArray | float) -> FloatArray:
    """Angles to [-pi, pi)."""
    return np.asarray((np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def euler_to_rot(rpy: FloatArray) -> FloatArray:
    """(..., 3) roll, pitch, yaw -> (..., 3, 3) world-from-body rotation matrices."""
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty((*rpy.shape[:-1], 3, 3))
    out[..., 0, 0] = cy * cp
    out[..., 0, 1] = cy * sp * sr - sy * cr
    out[..., 0, 2] = cy * sp * cr + sy * sr
    out[..., 1, 0] = sy * cp
    out[..., 1, 1] = sy * sp * sr + cy * cr
    out[..., 1, 2] = sy * sp * cr - cy * sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def rot_to_euler(rot: FloatArray) -> FloatArray:
    """(..., 3, 3) rotation matrices -> (..., 3) roll, pitch, yaw."""
    roll = np.arctan2(rot[..., 2, 1], rot[..., 2, 2])
    pitch = -np.arcsin(np.clip(rot[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(rot[..., 1, 0], rot[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


#: Rotation angle (rad) below which :func:`so3_exp` takes its coefficients from their Taylor
#: series: the first terms dropped (``theta^4 / 120`` and ``theta^4 / 720``) are then below
#: 1e-18, under float64 round-off, while the kept ``theta^2`` terms still count.
SO3_SERIES_BELOW_RAD = 1e-4


def so3_exp(phi: FloatArray) -> FloatArray:
    """Rodrigues' formula: rotation vectors ``phi`` (..., 3) -> rotation matrices (..., 3, 3).

    With ``theta = |phi|`` and ``K`` the cross-product matrix of ``phi`` (``K v = phi x v``)::

        Exp(phi) = I + a K + b K^2
        a = sin(theta) / theta                 = 1 - theta^2 / 6  + theta^4 / 120 - ...
        b = (1 - cos(theta)) / theta^2         = 1/2 - theta^2 / 24 + theta^4 / 720 - ...
          = 1/2 (sin(theta / 2) / (theta / 2))^2

    ``b`` is computed from its half-angle form: ``1 - cos(theta)`` cancels catastrophically
    for small angles (it is exactly 0 in float64 below theta ~ 1.5e-8). Below
    :data:`SO3_SERIES_BELOW_RAD` the two-term series are used, which also covers theta = 0.
    """
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = np.zeros((*phi.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2] = -phi[..., 2], phi[..., 1]
    k[..., 1, 0], k[..., 1, 2] = phi[..., 2], -phi[..., 0]
    k[..., 2, 0], k[..., 2, 1] = -phi[..., 1], phi[..., 0]
    small = theta < SO3_SERIES_BELOW_RAD
    t = np.where(small, 1.0, theta)  # no 0 / 0 in the branch np.where discards
    half_sinc = np.sin(0.5 * t) / (0.5 * t)
    theta2 = theta**2
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta2 / 24.0, 0.5 * half_sinc**2)
    return np.asarray(np.eye(3) + a * k + b * (k @ k), dtype=np.float64)


def so3_exp_one(phi: FloatArray) -> FloatArray:
    """:func:`so3_exp` of one rotation vector ``phi`` (3,) -> (3, 3), the same formula in
    scalar arithmetic (the IMU pre-integration calls it once per sample, where numpy's
    per-call overhead dominates). With ``K^2 = phi phi^T - theta^2 I``::

        Exp(phi) = I + a K + b (phi phi^T - theta^2 I)
    """
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    th2 = x * x + y * y + z * z
    if th2 < SO3_SERIES_BELOW_RAD**2:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        half_sinc = math.sin(0.5 * th) / (0.5 * th)
        a, b = math.sin(th) / th, 0.5 * half_sinc * half_sinc
    return np.array(
        [
            [1.0 + b * (x * x - th2), -a * z + b * x * y, a * y + b * x * z],
            [a * z + b * x * y, 1.0 + b * (y * y - th2), -a * x + b * y * z],
            [-a * y + b * x * z, a * x + b * y * z, 1.0 + b * (z * z - th2)],
        ]
    )


def euler_rates(rpy: FloatArray, omega_body: FloatArray) -> FloatArray:
    """Time derivatives of roll, pitch, yaw (..., 3) given the body rate (..., 3): the
    filter's form of :func:`euler_rates_zyx` (the same maths; the float operations are
    ordered as each caller has always computed them, so the tables stay bit for bit)."""
    r, p = rpy[..., 0], rpy[..., 1]
    wx, wy, wz = omega_body[..., 0], omega_body[..., 1], omega_body[..., 2]
    sr, cr, tp, cp = np.sin(r), np.cos(r), np.tan(p), np.cos(p)
    roll_dot = wx + sr * tp * wy + cr * tp * wz
    pitch_dot = cr * wy - sr * wz
    yaw_dot = (sr * wy + cr * wz) / cp
    return np.stack([roll_dot, pitch_dot, yaw_dot], axis=-1)


# -- quaternions, one column per component ---------------------------------------------


def _unit(
    qx: FloatArray, qy: FloatArray, qz: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The quaternions (x, y, z, w) normalised; a zero or non-finite one becomes NaN."""
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(norm > 1e-12, 1.0 / norm, np.nan)
    return qx * inv, qy * inv, qz * inv, qw * inv


def quaternion_to_euler_zyx(
    qx: FloatArray, qy: FloatArray, qz: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(roll, pitch, yaw) in rad of unit quaternions (x, y, z, w), Z-Y-X convention.

    The quaternions are normalised first; a zero or non-finite one gives NaN angles.
    """
    x, y, z, w = _unit(qx, qy, qz, qw)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quaternion_zyx(
    roll: FloatArray, pitch: FloatArray, yaw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(x, y, z, w) of the rotation R = Rz(yaw) Ry(pitch) Rx(roll), element-wise: the
    inverse of :func:`quaternion_to_euler_zyx`."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def rotate_body_to_world(
    q: tuple[FloatArray, FloatArray, FloatArray, FloatArray], v: tuple[FloatArray, ...]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotate body-frame vectors ``v`` (x, y, z) by unit quaternions ``q`` (x, y, z, w)."""
    x, y, z, w = _unit(*q)
    vx, vy, vz = v
    wx = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz
    wy = 2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz
    wz = 2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz
    return wx, wy, wz


def euler_rates_zyx(
    roll: FloatArray, pitch: FloatArray, p: FloatArray, q: FloatArray, r: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Z-Y-X Euler-angle rates (roll, pitch, yaw rates, rad/s) from body rates p, q, r (rad/s).

    roll' = p + tan(pitch) (q sin(roll) + r cos(roll)); pitch' = q cos(roll) - r sin(roll);
    yaw' = (q sin(roll) + r cos(roll)) / cos(pitch). Singular at pitch = +-90 degrees.
    """
    sr, cr = np.sin(roll), np.cos(roll)
    qr = q * sr + r * cr
    return p + np.tan(pitch) * qr, q * cr - r * sr, qr / np.cos(pitch)

"""Rotations for the pose filter, vectorised over leading axes.

Attitude is Z-Y-X Euler (roll, pitch, yaw): ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` maps
base_link vectors into ENU (world from body).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


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
    """Time derivatives of roll, pitch, yaw (..., 3) given the body rate (..., 3)."""
    r, p = rpy[..., 0], rpy[..., 1]
    wx, wy, wz = omega_body[..., 0], omega_body[..., 1], omega_body[..., 2]
    sr, cr, tp, cp = np.sin(r), np.cos(r), np.tan(p), np.cos(p)
    roll_dot = wx + sr * tp * wy + cr * tp * wz
    pitch_dot = cr * wy - sr * wz
    yaw_dot = (sr * wy + cr * wz) / cp
    return np.stack([roll_dot, pitch_dot, yaw_dot], axis=-1)

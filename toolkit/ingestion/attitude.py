"""Attitude from quaternions, Z-Y-X (yaw, pitch, roll) Euler convention, vectorised.

The truth pose (``nav_msgs/Odometry``) and ``geometry_msgs/QuaternionStamped`` headings carry
quaternions; the contract's tables carry Z-Y-X Euler angles and their rates.
"""

from __future__ import annotations

import numpy as np

from toolkit.ingestion.rows import FloatArray


def quaternion_to_euler_zyx(
    qx: FloatArray, qy: FloatArray, qz: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(roll, pitch, yaw) in rad of unit quaternions (x, y, z, w), Z-Y-X convention.

    The quaternions are normalised first; a zero or non-finite one gives NaN angles.
    """
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(norm > 1e-12, 1.0 / norm, np.nan)
    x, y, z, w = qx * inv, qy * inv, qz * inv, qw * inv
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def rotate_body_to_world(
    q: tuple[FloatArray, FloatArray, FloatArray, FloatArray], v: tuple[FloatArray, ...]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotate body-frame vectors ``v`` (x, y, z) by unit quaternions ``q`` (x, y, z, w)."""
    qx, qy, qz, qw = q
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(norm > 1e-12, 1.0 / norm, np.nan)
    x, y, z, w = qx * inv, qy * inv, qz * inv, qw * inv
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


__all__ = ["euler_rates_zyx", "quaternion_to_euler_zyx", "rotate_body_to_world"]

"""The pose filter's state vector, and means and residuals that respect its angles.

State vector ``x`` (16), all in the local ENU world frame unless said otherwise:

====  ===============  =====  ==============================================================
idx   name             unit   meaning
====  ===============  =====  ==============================================================
0-2   px, py, pz       m      position of the IMU (``imu_link`` origin)
3-5   vx, vy, vz       m/s    velocity of the IMU
6-8   roll,pitch,yaw   rad    attitude of base_link (Z-Y-X Euler; IMU axes = base_link axes)
9-11  bax, bay, baz    m/s^2  accelerometer bias (IMU frame)
12-14 bgx, bgy, bgz    rad/s  gyro bias (IMU frame)
15    ks               1      wheel-speed scale error: the odometer reads ``(1 + ks)`` times
                              the true forward speed (tyre radius, wear, load)
====  ===============  =====  ==============================================================

Angles: the state mean of the sigma points averages the attitude angles as wrapped offsets
from the first sigma point, and state and yaw residuals are wrapped, so a yaw near +-pi
averages correctly (:func:`state_mean`, :func:`state_residual`, :func:`angle_mean`,
:func:`angle_residual`). :func:`unscented_transform` takes them for a set of sigma points.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.geometry.rotations import wrap_angle

#: Dimension of the state vector.
DIM_X = 16
#: Slices of the state vector: position, velocity, attitude, accelerometer and gyro bias,
#: wheel-speed scale error.
POS, VEL, ATT, BA, BG = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
#: Index of the wheel-speed scale error (dimensionless) in the state vector.
SCALE = 15
#: Index of yaw in the state vector (the last attitude angle).
YAW = ATT.start + 2
#: The motion states (position, velocity, attitude), which an unobserved interval makes
#: uncertain; the biases (BA, BG) and the wheel scale follow them in the state vector.
MOTION = slice(POS.start, ATT.stop)
#: Components of a base_link-axis vector: forward (x) and lateral and vertical (y, z).
FORWARD, LATERAL_VERTICAL = slice(0, 1), slice(1, 3)
#: Standard gravity, m/s^2; gravity in ENU is (0, 0, -G).
G = 9.80665
GRAVITY = np.array([0.0, 0.0, -G])
#: States a dead-reckoning update (no GPS, compass or GPS track) is conditioned on: the
#: position and yaw (translating the whole solution, or turning it about gravity, changes no
#: body-frame measurement), the z gyro bias and the wheel scale (seen only through the
#: accelerometer, whose errors on a vehicle are larger than their signal). See
#: ``PoseUKF._conditioned``.
DEAD_RECKONING_GIVEN: tuple[int, ...] = (
    POS.start,
    POS.start + 1,
    POS.start + 2,
    YAW,
    BG.stop - 1,
    SCALE,
)


def state_residual(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b`` for states (..., 16), attitude angles wrapped."""
    d = np.asarray(a, dtype=np.float64) - b
    d[..., ATT] = wrap_angle(d[..., ATT])
    return d


def state_mean(sigmas: FloatArray, wm: FloatArray) -> FloatArray:
    """Weighted mean of states (M, 16); angles averaged as wrapped offsets from sigma 0."""
    ref = sigmas[0, ATT]
    x = wm @ sigmas
    x[ATT] = wrap_angle(ref + wm @ wrap_angle(sigmas[:, ATT] - ref))
    return x


def angle_residual(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b`` for angle measurements, wrapped."""
    return wrap_angle(np.asarray(a, dtype=np.float64) - b)


def angle_mean(zs: FloatArray, wm: FloatArray) -> FloatArray:
    """Weighted mean of angle measurements (M, k), wrapped."""
    ref = zs[0]
    return wrap_angle(ref + wm @ wrap_angle(zs - ref))


def plain_residual(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b``."""
    return np.asarray(a, dtype=np.float64) - b


def plain_mean(zs: FloatArray, wm: FloatArray) -> FloatArray:
    """Weighted mean of measurements (M, k)."""
    return np.asarray(wm @ zs, dtype=np.float64)


def unscented_transform(
    sigmas: FloatArray,
    wm: FloatArray,
    wc: FloatArray,
    noise_cov: FloatArray | None = None,
    mean_fn: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
    residual_fn: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Mean and covariance of transformed sigma points ``sigmas`` (M, k)::

        mean = mean_fn(sigmas, wm)                       (default: sum_i wm_i sigmas_i)
        d_i = residual_fn(sigmas_i, mean)                (default: sigmas_i - mean)
        cov = sum_i wc_i d_i d_i^T + noise_cov           (k, k)

    The same numbers as ``filterpy.kalman.unscented_transform``, on all M sigma points at
    once (filterpy loops over them when given a residual function).
    """
    mean = (mean_fn or plain_mean)(sigmas, wm)
    d = (residual_fn or plain_residual)(sigmas, mean)
    cov = (d.T * wc) @ d
    if noise_cov is not None:
        cov = cov + noise_cov
    return mean, cov


__all__ = [
    "ATT",
    "BA",
    "BG",
    "DEAD_RECKONING_GIVEN",
    "DIM_X",
    "FORWARD",
    "G",
    "GRAVITY",
    "LATERAL_VERTICAL",
    "MOTION",
    "POS",
    "SCALE",
    "VEL",
    "YAW",
    "angle_mean",
    "angle_residual",
    "plain_mean",
    "plain_residual",
    "state_mean",
    "state_residual",
    "unscented_transform",
]

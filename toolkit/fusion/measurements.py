"""The pose filter's measurement models, evaluated on all sigma points at once.

Measurement models (``R(rpy)`` world from body; ``l`` a lever arm from the IMU in base_link;
``w`` the bias-corrected gyro rate at the measurement time, a known input):

- GPS position (3): ``z = p + R(rpy) l_gps``; noise from the fix's diagonal covariance.
- GPS-compass yaw (1): ``z = yaw``; residual wrapped to [-pi, pi).
- Wheel speed (1): ``z = (1 + ks) (e_x . R(rpy)^T v + (w x l_axle)_x)``, the odometer's
  reading of the forward speed of the rear-axle centre (``l_axle`` = base_link origin, on
  the ground below the rear axle, from the IMU). Without ``ks`` a scale error of 0.3 % is a
  steady velocity bias that the GPS can correct only through the position, so the pose runs
  ahead of (or behind) the truth by that bias times the GPS correction's time constant
  (several seconds when IMU, wheels and NHC make the filter confident of its velocity).
- Attitude (2, optional): ``z = (roll, pitch)`` of base_link from an IMU that reports its
  orientation (:func:`roll_pitch_model`; :func:`attitude_model` adds yaw); residuals
  wrapped.
- Non-holonomic constraint (2): the lateral and vertical body velocity of the rear-axle
  centre are zero, ``z = (e_y, e_z) . (R(rpy)^T v + w x l_axle) = 0``, with
  :data:`NHC_STD_MPS`.

:class:`Measurement` carries one of them, with its reading, noise and gate, to
:meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`, which gates it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.state import (
    ATT,
    FORWARD,
    LATERAL_VERTICAL,
    POS,
    SCALE,
    VEL,
    YAW,
    plain_mean,
    plain_residual,
)
from toolkit.geometry.rotations import euler_to_rot

#: 1 sigma of the non-holonomic constraint (lateral and vertical axle speed), m/s.
NHC_STD_MPS = 0.3
#: chi-square (2 dof, p = 0.9999) gate for the non-holonomic constraint.
NHC_GATE_CHI2 = 18.42

MeasFn = Callable[[FloatArray], FloatArray]


def gps_model(lever_gps: FloatArray) -> MeasFn:
    """z = p + R(rpy) l_gps, the antenna's ENU position."""

    def hx(s: FloatArray) -> FloatArray:
        return np.asarray(s[:, POS] + euler_to_rot(s[:, ATT]) @ lever_gps, dtype=np.float64)

    return hx


def yaw_model(s: FloatArray) -> FloatArray:
    """z = yaw."""
    return np.asarray(s[:, YAW : YAW + 1], dtype=np.float64)


def axle_velocity_body(s: FloatArray, gyro: FloatArray, lever_axle: FloatArray) -> FloatArray:
    """Body-frame velocity of the rear-axle centre, (M, 3)."""
    rot = euler_to_rot(s[:, ATT])
    v_body = np.einsum("mji,mj->mi", rot, s[:, VEL])
    # w x l for one (3,) pair, written out: np.cross costs more than the rest of this model.
    w, lv = gyro, lever_axle
    w_x_l = np.array(
        [w[1] * lv[2] - w[2] * lv[1], w[2] * lv[0] - w[0] * lv[2], w[0] * lv[1] - w[1] * lv[0]]
    )
    return np.asarray(v_body + w_x_l, dtype=np.float64)


def wheel_model(gyro: FloatArray, lever_axle: FloatArray) -> MeasFn:
    """z = (1 + ks) x forward speed of the rear-axle centre (the odometer's reading)."""

    def hx(s: FloatArray) -> FloatArray:
        fwd = axle_velocity_body(s, gyro, lever_axle)[:, FORWARD]
        return np.asarray(fwd * (1.0 + s[:, SCALE : SCALE + 1]), dtype=np.float64)

    return hx


def attitude_model(s: FloatArray) -> FloatArray:
    """z = (roll, pitch, yaw) of base_link."""
    return np.asarray(s[:, ATT], dtype=np.float64)


def roll_pitch_model(s: FloatArray) -> FloatArray:
    """z = (roll, pitch) of base_link."""
    return np.asarray(s[:, ATT.start : ATT.start + 2], dtype=np.float64)


def nhc_model(gyro: FloatArray, lever_axle: FloatArray) -> MeasFn:
    """z = (lateral, vertical) body velocity of the rear-axle centre (observed as 0)."""

    def hx(s: FloatArray) -> FloatArray:
        return axle_velocity_body(s, gyro, lever_axle)[:, LATERAL_VERTICAL]

    return hx


@dataclass(frozen=True)
class Measurement:
    """One sensor's measurement for :meth:`PoseUKF.update_joint`: ``z`` (k,), noise
    covariance ``R`` (k, k), model ``hx`` (sigma points (M, 16) -> (M, k)), gate
    ``gate_chi2`` on ``y^T S^-1 y``, and how to average and subtract it (the angle
    versions for angles). ``name`` counts it as accepted or gated. ``robust``: beyond the
    gate it is down-weighted (noise inflated to bring ``y^T S^-1 y`` to the gate) instead of
    rejected; see :meth:`PoseUKF.update_joint`."""

    name: str
    z: FloatArray
    R: FloatArray
    hx: MeasFn
    gate_chi2: float
    mean_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_mean
    residual_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_residual
    robust: bool = False


__all__ = [
    "NHC_GATE_CHI2",
    "NHC_STD_MPS",
    "MeasFn",
    "Measurement",
    "attitude_model",
    "axle_velocity_body",
    "gps_model",
    "nhc_model",
    "roll_pitch_model",
    "wheel_model",
    "yaw_model",
]

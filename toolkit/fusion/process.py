"""The pose filter's process model: IMU pre-integration, the motion of a sigma point over
one filter step, and the process noise.

Process model (one filter step over ``[t_a, t_b]``, ``T = t_b - t_a``). The IMU samples
(accelerometer specific force ``f``, gyro rate ``w``, each held constant over the interval it
averages) are pre-integrated once, in the body frame at ``t_a``, with the prior mean's biases
``ba0, bg0`` (:class:`ImuIncrement`)::

    dR = prod Exp((w_j - bg0) dt_j)            dv = sum dR_j (f_j - ba0) dt_j
    dp = sum (dv_j dt_j + 1/2 dR_j (f_j - ba0) dt_j^2)

Each sigma point then moves in one vectorised step, with first-order bias corrections
(``dba = ba - ba0``, ``dbg = bg - bg0``; ``Jv = sum dR_j dt_j``, ``Jp`` likewise for dp)::

    R' = R(rpy) dR Exp(-dbg T)                 rpy' = euler(R')
    v' = v + g T + R(rpy) (dv - Jv dba)        g = (0, 0, -9.80665)
    p' = p + v T + 1/2 g T^2 + R(rpy) (dp - Jp dba)
    ba' = ba,  bg' = bg,  ks' = ks

Process noise (additive, per step, diagonal; :meth:`NoiseModel.q`): velocity
``accel_noise^2 T``, attitude ``gyro_noise^2 T``, biases and wheel scale ``walk^2 T``,
position ``accel_noise^2 T^3 / 3``, plus small floors (1e-9 m^2 on position, 1e-14, 1e-16
and 1e-14 on the accelerometer bias, gyro bias and wheel scale) that keep ``Q`` positive
definite for a tiny ``T``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.state import ATT, BA, BG, DIM_X, GRAVITY, POS, SCALE, VEL
from toolkit.geometry.rotations import euler_to_rot, rot_to_euler, so3_exp, so3_exp_one


@dataclass
class ImuIncrement:
    """IMU samples pre-integrated over one filter step, in the body frame at its start.

    ``ba0`` (3,) m/s^2 and ``bg0`` (3,) rad/s are the biases the samples are corrected by
    (the prior mean's); ``T`` s the time integrated so far; ``rot_inc`` (3, 3) ``dR``,
    ``dv`` (3,) m/s, ``dp`` (3,) m, and the bias Jacobians ``Jv`` (3, 3) s and ``Jp`` (3, 3)
    s^2, as in the module docstring. An accumulator: :meth:`add` one sample at a time.
    """

    ba0: FloatArray
    bg0: FloatArray
    T: float = 0.0
    rot_inc: FloatArray = field(default_factory=lambda: np.eye(3))
    dv: FloatArray = field(default_factory=lambda: np.zeros(3))
    dp: FloatArray = field(default_factory=lambda: np.zeros(3))
    Jv: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    Jp: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))

    def add(self, accel: FloatArray, gyro: FloatArray, dt: float) -> None:
        """Integrate one sample (specific force ``accel`` (3,) m/s^2, rate ``gyro`` (3,)
        rad/s, both in the IMU frame), held constant over ``dt`` seconds."""
        f = self.rot_inc @ (accel - self.ba0)
        half = 0.5 * dt * dt
        self.dp += self.dv * dt + f * half
        self.Jp += self.Jv * dt + self.rot_inc * half
        self.dv += f * dt
        self.Jv += self.rot_inc * dt
        self.rot_inc = self.rot_inc @ so3_exp_one((gyro - self.bg0) * dt)
        self.T += dt


def propagate(sigmas: FloatArray, inc: ImuIncrement) -> FloatArray:
    """The process model: states (M, 16) moved over one increment, (M, 16) out (see the
    module docstring)."""
    T = inc.T
    rot = euler_to_rot(sigmas[:, ATT])
    dba = sigmas[:, BA] - inc.ba0
    dbg = sigmas[:, BG] - inc.bg0
    rot_new = rot @ inc.rot_inc @ so3_exp(-dbg * T)
    dv = inc.dv - dba @ inc.Jv.T
    dp = inc.dp - dba @ inc.Jp.T
    out = sigmas.copy()
    out[:, POS] = (
        sigmas[:, POS]
        + sigmas[:, VEL] * T
        + 0.5 * GRAVITY * T * T
        + np.einsum("mij,mj->mi", rot, dp)
    )
    out[:, VEL] = sigmas[:, VEL] + GRAVITY * T + np.einsum("mij,mj->mi", rot, dv)
    out[:, ATT] = rot_to_euler(rot_new)
    return out


@dataclass(frozen=True)
class NoiseModel:
    """Process noise densities, each per sqrt(s): ``accel`` m/s^2, ``gyro`` rad/s,
    ``accel_bias_walk`` m/s^2, ``gyro_bias_walk`` rad/s, ``wheel_scale_walk`` 1/sqrt(s)."""

    accel: float
    gyro: float
    accel_bias_walk: float
    gyro_bias_walk: float
    wheel_scale_walk: float = 0.0

    def q(self, T: float) -> FloatArray:
        """Additive process noise covariance (16, 16) for a step of ``T`` seconds::

        Q = diag(accel^2 T^3 / 3 + 1e-9 (POS), accel^2 T (VEL), gyro^2 T (ATT),
                 accel_bias_walk^2 T + 1e-14 (BA), gyro_bias_walk^2 T + 1e-16 (BG),
                 wheel_scale_walk^2 T + 1e-14 (SCALE))
        """
        d = np.empty(DIM_X)
        d[POS] = self.accel**2 * T**3 / 3.0 + 1e-9
        d[VEL] = self.accel**2 * T
        d[ATT] = self.gyro**2 * T
        d[BA] = self.accel_bias_walk**2 * T + 1e-14
        d[BG] = self.gyro_bias_walk**2 * T + 1e-16
        d[SCALE] = self.wheel_scale_walk**2 * T + 1e-14
        return np.diag(d)


__all__ = ["ImuIncrement", "NoiseModel", "propagate"]

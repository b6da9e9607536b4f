"""The accelerometer's own noise, measured on the log, as process noise for odometry dead
reckoning (:mod:`toolkit.fusion.estimator`, ``[pose] dead_reckoning = "odometry"``).

With the configured Stanley-class ``accel_noise_mps2`` alone, the filter takes the integral of
a vibrating MEMS accelerometer for a better velocity than the wheels', gates them and drifts;
:class:`AccelNoise` measures the noise the accelerometer really has and :func:`vibration_q`
adds what it exceeds the configured noise by to the predict's process noise.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from toolkit.arrays import FloatArray
from toolkit.fusion.state import DIM_X, POS, VEL
from toolkit.geometry.rotations import euler_to_rot

#: Time constant of the running estimate of the accelerometer's noise in odometry dead
#: reckoning (:class:`AccelNoise`), s: long against the 20-100 Hz vibration it measures
#: (hundreds of samples), short against a change of terrain or speed.
ACCEL_NOISE_TAU_S = 2.0


class AccelNoise:
    """A causal running estimate of the accelerometer's white noise, per body axis.

    The mean square successive difference of a white sequence of variance ``sigma^2`` is
    ``2 sigma^2`` (von Neumann 1941, Ann. Math. Stat. 12(4)); half of it at the sample
    period is the Allan variance at ``tau_0``, whose velocity-random-walk density is
    ``N^2 = sigma^2 tau_0`` (IEEE Std 952-1997, annex C). So, per axis, with ``d_k = f_k -
    f_(k-1)`` and an exponential mean ``m_k = m_(k-1) + a (d_k^2 - m_(k-1))``, ``a = 1 -
    exp(-tau_0 / tau)`` (``tau`` = :data:`ACCEL_NOISE_TAU_S`)::

        N_i^2 = m_i tau_0 / 2                  (m/s^2)^2 s, body axis i

    A real change of acceleration between samples adds ``(jerk tau_0)^2`` to ``d_k^2``, a
    few (cm/s^2)^2 for a robot at 50 Hz; it can only raise ``N``, that is make the filter
    lean more on the wheels. Chassis vibration sampled at the IMU's rate (aliased: a 50 Hz
    IMU does not see a 30 Hz shake, it sees its samples) integrates, sample by sample, into
    a velocity error that is a random walk of density ``N``; on a skid-steer robot ``N``
    is several times the configured ``accel_noise_mps2`` (tuned for the Stanley-class IMU).
    """

    def __init__(self, head_accel: FloatArray, period: float) -> None:
        """Start from the mean square successive difference of ``head_accel`` (N, 3), the
        samples the initial attitude is taken from (zero if fewer than two)."""
        d = np.diff(head_accel, axis=0)
        self._m = (d**2).mean(axis=0) if d.shape[0] else np.zeros(3)
        self._period = period
        self._a = 1.0 - float(np.exp(-period / ACCEL_NOISE_TAU_S))
        self._last: FloatArray | None = None

    def window(self, accel: FloatArray) -> FloatArray:
        """The density ``N_i^2`` after each sample of ``accel`` (N, 3), (N, 3) out."""
        prev = accel[:1] if self._last is None else self._last[None, :]
        d2 = np.diff(accel, axis=0, prepend=prev) ** 2
        self._last = accel[-1].copy()
        # m_k = (1 - a) m_(k-1) + a d_k^2 as a first-order IIR filter with the carried state.
        m, zi = lfilter(
            [self._a], [1.0, self._a - 1.0], d2, axis=0, zi=((1.0 - self._a) * self._m)[None, :]
        )
        self._m = m[-1].copy()
        return np.asarray(m * (0.5 * self._period), dtype=np.float64)


def vibration_q(
    rpy: FloatArray, density2_body: FloatArray, accel_noise: float, T: float
) -> FloatArray:
    """Process noise (16, 16) for what the accelerometer's measured noise (``density2_body``
    (3,), ``N_i^2`` of :class:`AccelNoise`, body axes) exceeds the configured white noise
    ``accel_noise`` (m/s^2 per sqrt(s)) by, over a step of ``T`` s::

        M = R(rpy) diag(max(N_i^2 - accel_noise^2, 0)) R(rpy)^T
        Q_pp = M T^3 / 3,   Q_pv = Q_vp = M T^2 / 2,   Q_vv = M T

    (white acceleration noise integrated once into velocity and twice into position;
    positive semidefinite since ``[[T^3/3, T^2/2], [T^2/2, T]]`` is).
    """
    extra = np.maximum(np.asarray(density2_body, dtype=np.float64) - accel_noise**2, 0.0)
    rot = euler_to_rot(np.asarray(rpy, dtype=np.float64))
    m = (rot * extra) @ rot.T
    q = np.zeros((DIM_X, DIM_X))
    q[POS, POS] = m * T**3 / 3.0
    q[POS, VEL] = q[VEL, POS] = m * T**2 / 2.0
    q[VEL, VEL] = m * T
    return q


__all__ = ["ACCEL_NOISE_TAU_S", "AccelNoise", "vibration_q"]

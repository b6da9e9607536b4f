"""An IMU-driven unscented Kalman filter for the vehicle pose (paper sect. 3), on filterpy.

State vector ``x`` (15), all in the local ENU world frame unless said otherwise:

====  ===============  =====  ==============================================================
idx   name             unit   meaning
====  ===============  =====  ==============================================================
0-2   px, py, pz       m      position of the IMU (``imu_link`` origin)
3-5   vx, vy, vz       m/s    velocity of the IMU
6-8   roll,pitch,yaw   rad    attitude of base_link (Z-Y-X Euler; IMU axes = base_link axes)
9-11  bax, bay, baz    m/s^2  accelerometer bias (IMU frame)
12-14 bgx, bgy, bgz    rad/s  gyro bias (IMU frame)
====  ===============  =====  ==============================================================

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
    ba' = ba,  bg' = bg

Process noise (additive, per step): velocity ``accel_noise^2 T``, attitude
``gyro_noise^2 T``, biases ``walk^2 T``, position ``accel_noise^2 T^3 / 3``.

Measurement models (``R(rpy)`` world from body; ``l`` a lever arm from the IMU in base_link;
``w`` the bias-corrected gyro rate at the measurement time, a known input):

- GPS position (3): ``z = p + R(rpy) l_gps``; noise from the fix's diagonal covariance.
- GPS-compass yaw (1): ``z = yaw``; residual wrapped to [-pi, pi).
- Wheel speed (1): ``z = e_x . R(rpy)^T v + (w x l_axle)_x``, forward speed of the rear-axle
  centre (``l_axle`` = base_link origin, on the ground below the rear axle, from the IMU).
- Non-holonomic constraint (2): the lateral and vertical body velocity of the rear-axle
  centre are zero, ``z = (e_y, e_z) . (R(rpy)^T v + w x l_axle) = 0``, with
  :data:`NHC_STD_MPS`.

Every measurement is gated: the squared Mahalanobis distance of its innovation,
``y^T S^-1 y``, above the sensor's threshold rejects it; rejections are counted per sensor.

Angles: the state mean of the sigma points averages yaw as wrapped offsets from the first
sigma point, and state and yaw residuals are wrapped, so a yaw near +-pi averages correctly.

filterpy evaluates ``fx`` and ``hx`` one sigma point at a time and its unscented transform
loops over sigma points when given a residual function; :class:`PoseUKF` overrides
``compute_process_sigmas`` with the vectorised process model above, passes a vectorised
unscented transform to ``predict``, and implements the gated update over all sigma points
at once. filterpy's sigma points (MerweScaledSigmaPoints), weights and state are used as is.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from toolkit.fusion.rotations import FloatArray, euler_to_rot, rot_to_euler, so3_exp, wrap_angle

#: Dimension of the state vector.
DIM_X = 15
#: Slices of the state vector.
POS, VEL, ATT, BA, BG = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
YAW = 8
#: Standard gravity, m/s^2; gravity in ENU is (0, 0, -G).
G = 9.80665
GRAVITY = np.array([0.0, 0.0, -G])
#: 1 sigma of the non-holonomic constraint (lateral and vertical axle speed), m/s.
NHC_STD_MPS = 0.3
#: chi-square (2 dof, p = 0.9999) gate for the non-holonomic constraint.
NHC_GATE_CHI2 = 18.42

MeasFn = Callable[[FloatArray], FloatArray]


# --------------------------------------------------------------------------------------
# Angles in means and residuals
# --------------------------------------------------------------------------------------


def state_residual(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a - b`` for states (..., 15), attitude angles wrapped."""
    d = np.asarray(a, dtype=np.float64) - b
    d[..., ATT] = wrap_angle(d[..., ATT])
    return d


def state_mean(sigmas: FloatArray, wm: FloatArray) -> FloatArray:
    """Weighted mean of states (M, 15); angles averaged as wrapped offsets from sigma 0."""
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
    """filterpy's unscented transform, vectorised (its own loops over sigma points)."""
    mean = (mean_fn or plain_mean)(sigmas, wm)
    d = (residual_fn or plain_residual)(sigmas, mean)
    cov = (d.T * wc) @ d
    if noise_cov is not None:
        cov = cov + noise_cov
    return mean, cov


# --------------------------------------------------------------------------------------
# IMU pre-integration
# --------------------------------------------------------------------------------------


@dataclass
class ImuIncrement:
    """IMU samples pre-integrated over one filter step, in the body frame at its start."""

    ba0: FloatArray
    bg0: FloatArray
    T: float = 0.0
    rot_inc: FloatArray = field(default_factory=lambda: np.eye(3))
    dv: FloatArray = field(default_factory=lambda: np.zeros(3))
    dp: FloatArray = field(default_factory=lambda: np.zeros(3))
    Jv: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    Jp: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))

    def add(self, accel: FloatArray, gyro: FloatArray, dt: float) -> None:
        """Integrate one held IMU sample over ``dt`` seconds."""
        f = self.rot_inc @ (accel - self.ba0)
        half = 0.5 * dt * dt
        self.dp += self.dv * dt + f * half
        self.Jp += self.Jv * dt + self.rot_inc * half
        self.dv += f * dt
        self.Jv += self.rot_inc * dt
        self.rot_inc = self.rot_inc @ so3_exp((gyro - self.bg0) * dt)
        self.T += dt


def propagate(sigmas: FloatArray, inc: ImuIncrement) -> FloatArray:
    """The process model for states (M, 15) over one increment (see the module docstring)."""
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


# --------------------------------------------------------------------------------------
# Measurement models (all sigma points at once)
# --------------------------------------------------------------------------------------


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
    return np.asarray(v_body + np.cross(gyro, lever_axle), dtype=np.float64)


def wheel_model(gyro: FloatArray, lever_axle: FloatArray) -> MeasFn:
    """z = forward speed of the rear-axle centre."""

    def hx(s: FloatArray) -> FloatArray:
        return axle_velocity_body(s, gyro, lever_axle)[:, 0:1]

    return hx


def nhc_model(gyro: FloatArray, lever_axle: FloatArray) -> MeasFn:
    """z = (lateral, vertical) body velocity of the rear-axle centre (observed as 0)."""

    def hx(s: FloatArray) -> FloatArray:
        return axle_velocity_body(s, gyro, lever_axle)[:, 1:3]

    return hx


# --------------------------------------------------------------------------------------
# The filter
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NoiseModel:
    """Process noise densities (per sqrt(s))."""

    accel: float
    gyro: float
    accel_bias_walk: float
    gyro_bias_walk: float

    def q(self, T: float) -> FloatArray:
        """Additive process noise covariance for a step of ``T`` seconds."""
        d = np.empty(DIM_X)
        d[POS] = self.accel**2 * T**3 / 3.0 + 1e-9
        d[VEL] = self.accel**2 * T
        d[ATT] = self.gyro**2 * T
        d[BA] = self.accel_bias_walk**2 * T + 1e-14
        d[BG] = self.gyro_bias_walk**2 * T + 1e-16
        return np.diag(d)


class PoseUKF(UnscentedKalmanFilter):
    """filterpy's UKF with the pose models above, vectorised, with gated updates.

    ``gated`` counts rejected measurements per sensor name, ``accepted`` the used ones,
    ``last_d2`` is the squared Mahalanobis distance of the last measurement tried.
    """

    def __init__(
        self,
        x0: FloatArray,
        P0: FloatArray,
        noise: NoiseModel,
        *,
        alpha: float,
        beta: float,
        kappa: float,
    ) -> None:
        points = MerweScaledSigmaPoints(
            DIM_X, alpha=alpha, beta=beta, kappa=kappa, subtract=state_residual
        )
        super().__init__(
            dim_x=DIM_X,
            dim_z=1,
            dt=0.01,
            hx=yaw_model,
            fx=lambda s, dt: s,
            points=points,
            x_mean_fn=state_mean,
            residual_x=state_residual,
        )
        self.x = np.asarray(x0, dtype=np.float64).copy()
        self.P = np.asarray(P0, dtype=np.float64).copy()
        self.noise = noise
        self.gated: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self.last_d2 = 0.0
        self._inc: ImuIncrement | None = None

    def compute_process_sigmas(self, dt: float, fx: object = None, **fx_args: object) -> None:
        """All sigma points through :func:`propagate` in one call (filterpy loops)."""
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        if self._inc is None:
            self.sigmas_f = sigmas
        else:
            self.sigmas_f = propagate(sigmas, self._inc)

    def predict_imu(self, inc: ImuIncrement) -> None:
        """Predict over one pre-integrated IMU increment."""
        self._inc = inc
        self.Q = self.noise.q(inc.T)
        try:
            self.predict(dt=inc.T, UT=unscented_transform)
        finally:
            self._inc = None

    def update_gated(
        self,
        name: str,
        z: FloatArray,
        R: FloatArray,
        hx: MeasFn,
        gate_chi2: float,
        *,
        mean_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_mean,
        residual_fn: Callable[[FloatArray, FloatArray], FloatArray] = plain_residual,
    ) -> bool:
        """One measurement update, rejected (and counted) when its innovation is gated."""
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        zs = hx(sigmas)
        zp, S = unscented_transform(zs, self.Wm, self.Wc, R, mean_fn, residual_fn)
        y = residual_fn(np.asarray(z, dtype=np.float64), zp)
        S_inv = np.linalg.inv(S)
        d2 = float(y @ S_inv @ y)
        self.last_d2 = d2
        if not np.isfinite(d2) or d2 > gate_chi2:
            self.gated[name] += 1
            return False
        dx = state_residual(sigmas, self.x)
        dz = residual_fn(zs, zp)
        Pxz = (dx.T * self.Wc) @ dz
        K = Pxz @ S_inv
        x = self.x + K @ y
        x[ATT] = wrap_angle(x[ATT])
        P = self.P - K @ S @ K.T
        self.x = x
        self.P = 0.5 * (P + P.T)
        self.accepted[name] += 1
        return True


__all__ = [
    "DIM_X",
    "GRAVITY",
    "ImuIncrement",
    "NoiseModel",
    "PoseUKF",
    "angle_mean",
    "angle_residual",
    "gps_model",
    "nhc_model",
    "propagate",
    "state_mean",
    "state_residual",
    "unscented_transform",
    "wheel_model",
    "yaw_model",
]

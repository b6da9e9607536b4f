"""What the pose estimator (:func:`toolkit.fusion.estimator.estimate_stream`) takes and gives:
the low-rate sensor arrays, the IMU stream's windows, the filter's settings, and the output
rows with the filter's accounting."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.process import NoiseModel


@dataclass(frozen=True)
class SensorData:
    """Sensor arrays on the log clock (seconds relative to ``t0_ns``), ENU metres."""

    t0_ns: int
    imu_t: FloatArray
    accel: FloatArray
    gyro: FloatArray
    gps_t: FloatArray  # valid fixes only
    gps_enu: FloatArray  # antenna position
    gps_var: FloatArray  # (K, 3) variances
    head_t: FloatArray
    head_yaw: FloatArray
    head_var: FloatArray
    wheel_t: FloatArray
    wheel_speed: FloatArray
    #: Base_link attitude the IMU reports (none: empty): times (K,), roll-pitch-yaw (K, 3)
    #: rad, variances (K, 3) rad^2.
    att_t: FloatArray = field(default_factory=lambda: np.zeros(0))
    att_rpy: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    att_var: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass(frozen=True)
class FilterSettings:
    """Noise, gates, sigma points, lever arms (from the IMU, base_link axes)."""

    noise: NoiseModel
    alpha: float
    beta: float
    kappa: float
    gate_gps: float
    gate_heading: float
    gate_wheels: float
    wheel_var: float
    init_pos_std: float
    init_vel_std: float
    init_att_std: float
    lever_gps: FloatArray
    lever_axle: FloatArray
    output_rate_hz: float
    #: 1 sigma of the wheel-speed scale error at the start (dimensionless).
    init_wheel_scale_std: float = 0.01
    #: Consecutive gated GPS fixes after which position and velocity are re-initialised
    #: from the GPS (0: never).
    reinit_after_gated_fixes: int = 0
    #: chi-square gate of the IMU-reported roll and pitch (2 dof).
    gate_attitude: float = 18.42
    #: Shortest straight GPS track that gives the heading without a compass, m.
    track_min_distance_m: float = 5.0
    #: Dead reckoning without any fix: ``inertial`` or ``odometry`` (module docstring).
    dead_reckoning: str = "inertial"


@dataclass
class EstimateResult:
    """Output rows (columns of the pose table) and the filter's accounting."""

    columns: dict[str, FloatArray]
    t_ns: np.ndarray
    gated: dict[str, int]
    accepted: dict[str, int]
    imu_gaps_bridged: int
    imu_gaps_restarted: int
    epochs: int
    imu_samples: int
    heading_source: str
    warnings: list[str] = field(default_factory=list)
    reinitialised: int = 0
    #: Measurements used beyond their gate with inflated noise (odometry dead reckoning's
    #: wheels), per sensor name; also counted in ``accepted``.
    down_weighted: dict[str, int] = field(default_factory=dict)


ImuWindow = tuple[FloatArray, FloatArray, FloatArray]
"""One window of IMU samples in time order: (t (N,), accel (N, 3), gyro (N, 3))."""

OutputChunk = tuple[np.ndarray, dict[str, FloatArray]]
"""Output rows of one window: (t_ns (M,), pose columns)."""


__all__ = ["EstimateResult", "FilterSettings", "ImuWindow", "OutputChunk", "SensorData"]

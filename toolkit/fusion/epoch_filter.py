"""The estimator's filter loop: the IMU pre-integrated segment by segment, a predict and one
joint update at every epoch, and the state a window of IMU samples leaves for the next.

An IMU window's samples and the epochs inside it cut time into *segments*, each ending on a
sample or an epoch. Between epochs the IMU is pre-integrated sample by sample
(:class:`~toolkit.fusion.process.ImuIncrement`, the one Python loop per IMU sample); the
increments at every segment end, with the posterior mean they start from, are kept in a
:class:`Segments` so that the mean can be carried to every segment end afterwards
(:mod:`toolkit.fusion.pose_output`). At each epoch (:meth:`EpochFilter._epoch`): predict,
then one joint update with whatever was measured then, one :class:`Measurement` per sensor
(:func:`gps_measurement`, :func:`compass_measurement`, :func:`track_measurement`,
:func:`attitude_measurement`, :func:`wheel_measurement`, :func:`nhc_measurement`), each gated
on its own innovation (:meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`).

An IMU interval longer than 1.5 nominal periods is a gap; up to
:data:`~toolkit.fusion.epochs.MAX_BRIDGE_S` it is bridged (the next sample's reading held
across it), a longer one is crossed at constant velocity and attitude for at most
:data:`~toolkit.fusion.epochs.MAX_CROSS_S`, and the next epoch restarts the filter
(:meth:`~toolkit.fusion.ukf.PoseUKF.restart`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray
from toolkit.fusion.accel_noise import AccelNoise, vibration_q
from toolkit.fusion.epochs import MAX_BRIDGE_S, MAX_CROSS_S, MAX_STEP_S
from toolkit.fusion.estimator_io import FilterSettings, SensorData
from toolkit.fusion.measurements import (
    NHC_GATE_CHI2,
    NHC_STD_MPS,
    Measurement,
    gps_model,
    nhc_model,
    roll_pitch_model,
    wheel_model,
    yaw_model,
)
from toolkit.fusion.process import ImuIncrement
from toolkit.fusion.state import (
    ATT,
    BA,
    BG,
    DEAD_RECKONING_GIVEN,
    DIM_X,
    GRAVITY,
    POS,
    SCALE,
    VEL,
    YAW,
    angle_mean,
    angle_residual,
)
from toolkit.fusion.track_heading import TRACK_YAW_FLOOR_RAD, YawHistory, track_headings
from toolkit.fusion.ukf import PoseUKF
from toolkit.geometry.rotations import euler_to_rot, wrap_angle


def initial_state(
    d: SensorData, s: FilterSettings, att0: FloatArray, t_start: float, heading_source: str
) -> tuple[FloatArray, FloatArray]:
    """The filter's first mean ``x0`` (16,) and covariance ``P0`` (16, 16), diagonal.

    Position (IMU): the first fix at or after ``t_start`` less the antenna's lever arm,
    ``p = z - R(att0) l_gps``; without any fix, base_link at the local origin, ``p = -R(att0)
    l_axle``. Velocity: the wheel speed at ``t_start`` along the body x axis (0 without
    wheels). Standard deviations: the configured ones for position, velocity and attitude
    (yaw 0.3 rad from a GPS track or with no heading at all), 0.1 m/s^2 accelerometer bias,
    0.005 rad/s gyro bias, ``init_wheel_scale_std`` wheel scale.
    """
    rot0 = euler_to_rot(att0)
    x0 = np.zeros(DIM_X)
    if d.gps_t.size:
        i_fix = min(int(np.searchsorted(d.gps_t, t_start)), d.gps_t.size - 1)
        x0[POS] = d.gps_enu[i_fix] - rot0 @ s.lever_gps
    else:  # base_link at the local origin; the IMU is -l_axle from it
        x0[POS] = -(rot0 @ s.lever_axle)
    speed0 = float(np.interp(t_start, d.wheel_t, d.wheel_speed)) if d.wheel_t.size else 0.0
    x0[VEL] = rot0 @ np.array([speed0, 0.0, 0.0])
    x0[ATT] = att0
    p0 = np.zeros(DIM_X)
    p0[POS] = s.init_pos_std**2
    p0[VEL] = s.init_vel_std**2
    p0[ATT] = s.init_att_std**2
    if heading_source in ("gps_track", "none"):
        p0[YAW] = 0.3**2
    p0[BA] = 0.1**2
    p0[BG] = 0.005**2
    p0[SCALE] = s.init_wheel_scale_std**2
    return x0, np.diag(p0)


def reinitialise(
    ukf: PoseUKF, d: SensorData, gi: int, t: float, streak: int, s: FilterSettings, P0: FloatArray
) -> None:
    """Put a filter that every fix is gated against back on the GPS.

    Position (IMU) from the fix ``gi``: ``p = z - R(rpy) l_gps``. Velocity: the wheel
    speed along the current attitude, ``v = R(rpy) (u / (1 + ks), 0, 0)``, where the log
    has wheel speeds at ``t``; else the mean velocity of the gated fixes, ``(z_gi -
    z_first) / (t_gi - t_first)``. Their covariance goes back to ``P0``'s
    (:meth:`PoseUKF.reset_motion`); attitude, biases and wheel scale are kept.
    """
    x = ukf.x
    rot = euler_to_rot(x[ATT])
    pos = d.gps_enu[gi] - rot @ s.lever_gps
    if d.wheel_t.size and d.wheel_t[0] <= t <= d.wheel_t[-1]:
        speed = float(np.interp(t, d.wheel_t, d.wheel_speed)) / (1.0 + float(x[SCALE]))
        vel = rot @ np.array([speed, 0.0, 0.0])
    else:
        first = max(gi - streak + 1, 0)
        dt = float(d.gps_t[gi] - d.gps_t[first])
        vel = (d.gps_enu[gi] - d.gps_enu[first]) / dt if dt > 0.0 else np.zeros(3)
    ukf.reset_motion(np.concatenate([pos, vel]), P0)


# --------------------------------------------------------------------------------------
# One measurement per sensor at an epoch
# --------------------------------------------------------------------------------------


def gps_measurement(d: SensorData, gi: int, s: FilterSettings) -> Measurement:
    """The antenna's ENU position of fix ``gi`` (m), its diagonal covariance (m^2)."""
    return Measurement(
        "gps", d.gps_enu[gi], np.diag(d.gps_var[gi]), gps_model(s.lever_gps), s.gate_gps
    )


def compass_measurement(d: SensorData, hi: int, s: FilterSettings) -> Measurement:
    """The compass yaw of reading ``hi`` (rad, ENU), its variance (rad^2)."""
    return Measurement(
        "heading",
        d.head_yaw[hi : hi + 1],
        d.head_var[hi : hi + 1, None],
        yaw_model,
        s.gate_heading,
        angle_mean,
        angle_residual,
    )


def track_measurement(yaw_rad: FloatArray, var_rad2: float, s: FilterSettings) -> Measurement:
    """The yaw ``yaw_rad`` (1,) from the GPS track, carried to now (rad), of variance
    ``var_rad2 +`` :data:`~toolkit.fusion.track_heading.TRACK_YAW_FLOOR_RAD` ``^2``."""
    return Measurement(
        "gps_track",
        yaw_rad,
        np.array([[var_rad2 + TRACK_YAW_FLOOR_RAD**2]]),
        yaw_model,
        s.gate_heading,
        angle_mean,
        angle_residual,
    )


def attitude_measurement(d: SensorData, ai: int, s: FilterSettings) -> Measurement:
    """The roll and pitch (rad) the IMU reported at ``ai``, their variances (rad^2)."""
    return Measurement(
        "imu_attitude",
        d.att_rpy[ai, :2],
        np.diag(d.att_var[ai, :2]),
        roll_pitch_model,
        s.gate_attitude,
        angle_mean,
        angle_residual,
    )


def wheel_measurement(
    speed_mps: float, w_radps: FloatArray, s: FilterSettings, *, robust: bool
) -> Measurement:
    """The odometer's forward speed (m/s) with the bias-corrected gyro rate ``w_radps`` (3,)
    as the known input of its model; ``robust``: down-weighted beyond its gate, not dropped."""
    return Measurement(
        "wheels",
        np.array([speed_mps]),
        np.array([[s.wheel_var]]),
        wheel_model(w_radps, s.lever_axle),
        s.gate_wheels,
        robust=robust,
    )


def nhc_measurement(w_radps: FloatArray, s: FilterSettings) -> Measurement:
    """The non-holonomic constraint: zero lateral and vertical axle speed, 1 sigma
    :data:`~toolkit.fusion.measurements.NHC_STD_MPS`."""
    return Measurement(
        "nhc",
        np.zeros(2),
        np.eye(2) * NHC_STD_MPS**2,
        nhc_model(w_radps, s.lever_axle),
        NHC_GATE_CHI2,
    )


# --------------------------------------------------------------------------------------
# The loop's state
# --------------------------------------------------------------------------------------


@dataclass
class Segments:
    """The segment ends of one IMU window (n of them): times ``t`` (n,) s, which are epochs
    ``is_epoch`` (n,), and per end the increment integrated since the last epoch (``tau``
    (n,) s, ``rot_inc`` ``dR`` (n, 3, 3), ``dv`` (n, 3) m/s, ``dp`` (n, 3) m, in the body
    frame at the epoch), the bias-corrected gyro rate ``w`` (n, 3) rad/s, the posterior mean
    the increment starts from ``base`` (n, 16), and at epochs the new posterior ``post``
    (n, 16; undefined elsewhere)."""

    t: FloatArray
    is_epoch: NDArray[np.bool_]
    tau: FloatArray
    rot_inc: FloatArray
    dv: FloatArray
    dp: FloatArray
    w: FloatArray
    base: FloatArray
    post: FloatArray

    @staticmethod
    def empty(t: FloatArray, is_epoch: NDArray[np.bool_]) -> Segments:
        n = t.size
        return Segments(
            t,
            is_epoch,
            np.empty(n),
            np.empty((n, 3, 3)),
            np.empty((n, 3)),
            np.empty((n, 3)),
            np.empty((n, 3)),
            np.empty((n, DIM_X)),
            np.empty((n, DIM_X)),
        )


class EpochFilter:
    """The causal filter over a stream of IMU windows (module docstring): :meth:`window` per
    window, in time order; the accounting is read afterwards from its attributes."""

    def __init__(
        self,
        d: SensorData,
        s: FilterSettings,
        att0: FloatArray,
        *,
        t_start: float,
        t_end: float,
        heading_source: str,
        epochs: FloatArray,
        period: float,
        accel_noise: AccelNoise,
        warnings: list[str],
    ) -> None:
        self._d, self._s = d, s
        self._t_start, self._t_end, self._period = t_start, t_end, period
        self._epochs = epochs
        self._accel_noise = accel_noise
        self.warnings = warnings
        x0, self._P0 = initial_state(d, s, att0, t_start, heading_source)
        self.ukf = PoseUKF(x0, self._P0, s.noise, alpha=s.alpha, beta=s.beta, kappa=s.kappa)
        if heading_source == "compass":
            self._track_yaw = self._track_var = self._track_t = np.full(d.gps_t.size, np.nan)
        else:
            self._track_yaw, self._track_var, self._track_t = track_headings(
                d, s.track_min_distance_m
            )
        self._yaw_history = YawHistory()
        self._heading_idx = {float(t): i for i, t in enumerate(d.head_t.tolist())}
        self._gps_idx = {float(t): i for i, t in enumerate(d.gps_t.tolist())}
        # Odometry dead reckoning: every update conditioned on what it must not move
        # (toolkit.fusion.state.DEAD_RECKONING_GIVEN).
        odometry = heading_source == "local" and s.dead_reckoning == "odometry"
        self._given = DEAD_RECKONING_GIVEN if odometry else ()
        self._post = self.ukf.x.copy()  # posterior at the start of the current epoch interval
        self._inc = ImuIncrement(self.ukf.x[BA].copy(), self.ukf.x[BG].copy())
        self._restart_pending = False
        self._lost_track_s = 0.0  # the longest gap not crossed since the last fix
        self._prev_imu_t: float | None = None
        self._prev_bound = t_start  # the last segment end handled
        self._gps_streak = 0  # consecutive gated fixes
        self._last_att = -1  # index of the last IMU attitude used
        self.n_bridged = self.n_restart = self.n_imu = self.n_reinit = 0

    def window(self, wt: FloatArray, accel: FloatArray, gyro: FloatArray) -> Segments | None:
        """Run the filter over one window of IMU samples (times ``wt`` (N,) s, specific force
        ``accel`` (N, 3) m/s^2, rate ``gyro`` (N, 3) rad/s); its segment ends, or None when
        it has none after the last one handled."""
        if wt.size == 0:
            return None
        period = self._period
        w_prev = (wt[0] - period) if self._prev_imu_t is None else self._prev_imu_t
        imu_dt = np.diff(wt, prepend=w_prev)
        self._prev_imu_t = float(wt[-1])
        # Odometry dead reckoning: the accelerometer's own noise, measured (AccelNoise).
        acc_density2 = self._accel_noise.window(accel) if self._given else None
        self._count_gaps(wt, imu_dt)
        t_hi = float(wt[-1])
        if t_hi <= self._t_start:
            return None
        lo = self._prev_bound
        ep_w = self._epochs[(self._epochs > lo) & (self._epochs <= t_hi)]
        bounds = np.union1d(wt[(wt > lo) & (wt <= self._t_end)], ep_w)
        if bounds.size == 0:
            return None
        seg_dt = np.diff(bounds, prepend=lo)
        seg_imu = np.searchsorted(wt, bounds, side="left")
        seg = Segments.empty(bounds, np.isin(bounds, ep_w))
        gap_len = imu_dt[seg_imu]
        restart_seg = (gap_len > 1.5 * period) & (gap_len > MAX_BRIDGE_S)
        for j in range(bounds.size):
            i = int(seg_imu[j])
            seg.base[j] = self._post
            self._integrate(accel, gyro, i, float(seg_dt[j]), bool(restart_seg[j]))
            inc = self._inc
            seg.tau[j], seg.rot_inc[j], seg.dv[j], seg.dp[j] = inc.T, inc.rot_inc, inc.dv, inc.dp
            seg.w[j] = gyro[min(i, gyro.shape[0] - 1)] - inc.bg0
            if not seg.is_epoch[j]:
                continue
            a2 = None
            if acc_density2 is not None:
                a2 = acc_density2[min(i, acc_density2.shape[0] - 1)]
            seg.post[j] = self._epoch(float(bounds[j]), seg.w[j], a2)
        self._prev_bound = float(bounds[-1])
        return seg

    def _count_gaps(self, wt: FloatArray, imu_dt: FloatArray) -> None:
        """Count the window's bridged and restarting IMU gaps and its samples after the
        start."""
        after = wt > self._t_start
        gap_w = (imu_dt > 1.5 * self._period) & after
        self.n_restart += int((imu_dt[gap_w] > MAX_BRIDGE_S).sum())
        self.n_bridged += int(gap_w.sum() - (imu_dt[gap_w] > MAX_BRIDGE_S).sum())
        self.n_imu += int(np.count_nonzero(after & (wt <= self._t_end)))

    def _integrate(
        self, accel: FloatArray, gyro: FloatArray, i: int, dt: float, restart: bool
    ) -> None:
        """Add sample ``i`` held over ``dt`` s to the increment; across a gap too long to
        bridge, the specific force that holds velocity and attitude (``f = dR^T R^T (-g) +
        ba0``, rate ``bg0``) for at most :data:`~toolkit.fusion.epochs.MAX_CROSS_S`, and the
        next epoch restarts the filter."""
        inc = self._inc
        if restart:
            f_hold = inc.rot_inc.T @ euler_to_rot(self._post[ATT]).T @ (-GRAVITY) + inc.ba0
            inc.add(f_hold, inc.bg0, min(dt, MAX_CROSS_S))
            self._restart_pending = True
            if dt > MAX_CROSS_S:
                self._lost_track_s = max(self._lost_track_s, dt)
        else:
            inc.add(accel[i], gyro[i], dt)

    def _epoch(self, t: float, w_now: FloatArray, accel_density2: FloatArray | None) -> FloatArray:
        """Predict to the epoch ``t`` (s) and update with what was measured then; the new
        posterior mean (16,), from which the next increment starts."""
        ukf, inc = self.ukf, self._inc
        if accel_density2 is None:
            ukf.predict(inc)
        else:
            # The wheels are the velocity reference here: a filter that took the
            # accelerometer for cleaner than it is would prefer its own integral of a
            # vibrating MEMS accelerometer to them, gate them, and drift (issue 27, 17).
            ukf.predict(
                inc, vibration_q(self._post[ATT], accel_density2, self._s.noise.accel, inc.T)
            )
        if self._restart_pending:
            ukf.restart(self._P0)
            self._restart_pending = False
        gi = self._gps_idx.get(t)
        # Everything measured at this epoch updates from one sigma-point draw, each
        # sensor gated on its own innovation (PoseUKF.update_joint).
        blocks = self._measurements(t, gi, w_now)
        if gi is not None and self._lost_track_s > 0.0:
            # After a gap too long to cross, the first fix says where the vehicle is.
            reinitialise(ukf, self._d, gi, t, 1, self._s, self._P0)
            self.warnings.append(
                f"IMU gap of {self._lost_track_s:.1f} s (longer than {MAX_CROSS_S} s) before "
                f"t = {t:.1f} s: position and velocity re-initialised from the GPS"
            )
            self.n_reinit += 1
            self._lost_track_s = 0.0
        flags = ukf.update_joint(blocks, given=self._given)
        if gi is not None:
            self._after_fix(gi, t, flags[0])
        post = ukf.x.copy()
        self._post = post
        self._yaw_history.add(t, float(post[YAW]))
        self._inc = ImuIncrement(ukf.x[BA].copy(), ukf.x[BG].copy())
        return post

    def _after_fix(self, gi: int, t: float, accepted: bool) -> None:
        """Count the fix ``gi`` into the streak of gated ones; after
        ``reinit_after_gated_fixes`` in a row, re-initialise from the GPS."""
        s = self._s
        self._gps_streak = 0 if accepted else self._gps_streak + 1
        if s.reinit_after_gated_fixes and self._gps_streak >= s.reinit_after_gated_fixes:
            reinitialise(self.ukf, self._d, gi, t, self._gps_streak, s, self._P0)
            self.warnings.append(
                f"{self._gps_streak} GPS fixes in a row gated at t = {t:.1f} s: position "
                "and velocity re-initialised from the GPS"
            )
            self.n_reinit += 1
            self._gps_streak = 0

    def _measurements(self, t: float, gi: int | None, w_now: FloatArray) -> list[Measurement]:
        """What was measured at the epoch ``t`` (s), the GPS fix (``gi``) first."""
        d, s = self._d, self._s
        blocks: list[Measurement] = []
        if gi is not None:
            blocks.append(gps_measurement(d, gi, s))
        hi = self._heading_idx.get(t)
        if hi is not None:
            blocks.append(compass_measurement(d, hi, s))
        track = self._track_yaw_now(gi)
        if track is not None:
            blocks.append(track_measurement(*track, s))
        ai = int(np.searchsorted(d.att_t, t, side="right")) - 1
        if ai > self._last_att and t - d.att_t[ai] <= MAX_STEP_S:
            # The latest orientation the IMU reported, once: its roll and pitch (gravity-
            # referenced); its yaw is not used as a heading (see toolkit.fusion.estimator).
            self._last_att = ai
            blocks.append(attitude_measurement(d, ai, s))
        if d.wheel_t.size and d.wheel_t[0] <= t <= d.wheel_t[-1]:
            speed = float(np.interp(t, d.wheel_t, d.wheel_speed))
            # Odometry dead reckoning: the wheels are the only velocity reference, so an
            # outlier is down-weighted, never dropped.
            blocks.append(wheel_measurement(speed, w_now, s, robust=bool(self._given)))
        blocks.append(nhc_measurement(w_now, s))
        return blocks

    def _track_yaw_now(self, gi: int | None) -> tuple[FloatArray, float] | None:
        """No compass: the direction of the latest straight GPS track at fix ``gi``, which
        is the yaw at the run's mean time, carried to now by the turn made since (rad, (1,)),
        and its variance (rad^2); None without one."""
        ti = gi if gi is not None and np.isfinite(self._track_yaw[gi]) else None
        if ti is None:
            return None
        turn = self._yaw_history.turn_since(float(self._track_t[ti]), float(self.ukf.x[YAW]))
        if turn is None:
            return None
        return wrap_angle(self._track_yaw[ti : ti + 1] + turn), float(self._track_var[ti])


__all__ = [
    "EpochFilter",
    "Segments",
    "attitude_measurement",
    "compass_measurement",
    "gps_measurement",
    "initial_state",
    "nhc_measurement",
    "reinitialise",
    "track_measurement",
    "wheel_measurement",
]

"""The causal pose estimator: sensor arrays in, 100 Hz base_link pose out.

Filter steps ("epochs") fall on every valid GPS fix and every compass reading, with filler
epochs so that no step is longer than :data:`~toolkit.fusion.epochs.MAX_STEP_S` (GPS dropouts
coast on IMU, wheels and the non-holonomic constraint). Between epochs the IMU is
pre-integrated sample by sample (the one Python loop per IMU sample); the same increments
carry the posterior mean of the last epoch forward to every IMU sample, which gives the
output between filter steps without using anything measured later
(:mod:`toolkit.fusion.pose_output`). At each epoch: predict, then one joint update with
whatever was measured then (GPS, compass yaw, the IMU's own roll and pitch, wheel speed, and
the non-holonomic constraint), each sensor gated on its own innovation
(:mod:`toolkit.fusion.epoch_filter`, :meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`),
except the wheels in odometry dead reckoning (below). This module is the driver over those
steps; ``docs/pose.md`` says how to choose between the modes, with the measurements behind
the choices.

Heading: from the compass when there is one; else from the GPS track
(:mod:`toolkit.fusion.track_heading`): the filter starts once a run of fixes lies on a
straight line long enough for its direction, whatever the speed, and afterwards the direction
of the latest straight stretch of the track, carried from the stretch's mean time to now by
the turn the filter made since, is a yaw measurement at every fix (``gps_track``, variance
``2 sigma_h^2 / L^2 + TRACK_YAW_FLOOR_RAD^2``, gated like the compass). An IMU that reports
its orientation contributes its roll and pitch (gravity-referenced) as measurements; its yaw
is not used as a heading: an uncalibrated magnetometer's yaw differs from the GPS track by an
amount that changes with the direction of travel (-90 to -147 deg on the one real log here),
which no fixed offset absorbs.

No GPS fix at all: the filter dead-reckons on IMU, wheel speeds and the non-holonomic
constraint in a local frame whose origin and zero yaw are the first pose (heading source
``local``), starting with the wheel speeds, in one of two modes (``[pose] dead_reckoning``):

- ``inertial``: wheel speed and NHC update every state, so the accelerometer can correct the
  heading and the z gyro bias (the centripetal ``v w_z`` against the gyro, the direction of
  the integrated velocity against the body axis): real information on a fast vehicle with a
  clean IMU.
- ``odometry``: the updates are conditioned on position, yaw, z gyro bias and wheel scale
  (:data:`~toolkit.fusion.state.DEAD_RECKONING_GIVEN`, why in
  ``PoseUKF._conditioned``): the heading is the gyro's integral and the position the integral
  of the velocity the wheels and NHC keep on the body axes, the UKF still giving roll, pitch
  and a 3-D path. It is for a slow robot with a MEMS IMU, where a lateral accelerometer error of
  0.05 m/s^2 equals a 3 deg/s yaw-rate error at 1 m/s. The velocity's process noise is then
  at least the accelerometer's own noise as measured on the log
  (:mod:`toolkit.fusion.accel_noise`): else the filter takes the integral of a vibrating MEMS
  accelerometer for a better velocity than the wheels', gates them and drifts. Nor is a
  wheel reading rejected: beyond its gate it is down-weighted, its variance inflated until
  its innovation is at the gate (``robust``, :meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`),
  and counted (``down_weighted``): the wheels are the only velocity reference here, and a
  rejected reading leaves the velocity to the accelerometer's integral, worse than a
  slipping track's reading.

Recovery: after ``reinit_after_gated_fixes`` GPS fixes in a row are gated, position and
velocity are taken from the GPS again (:func:`~toolkit.fusion.epoch_filter.reinitialise`),
counted and warned about, so a filter that has drifted away is never locked out by its own
gate.

IMU gaps: a sample interval longer than 1.5 nominal periods is a gap. Gaps up to
:data:`~toolkit.fusion.epochs.MAX_BRIDGE_S` are bridged (the next sample's reading is held
across the gap); longer ones restart the filter: the gap is crossed at constant velocity and
attitude, and the covariance of position, velocity and attitude is raised to at least its
initial value at every epoch in the gap (:meth:`~toolkit.fusion.ukf.PoseUKF.restart`, which
says how and why).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.accel_noise import AccelNoise
from toolkit.fusion.epoch_filter import EpochFilter
from toolkit.fusion.epochs import MAX_BRIDGE_S, filter_epochs
from toolkit.fusion.estimator_io import (
    EstimateResult,
    FilterSettings,
    ImuWindow,
    OutputChunk,
    SensorData,
)
from toolkit.fusion.pose_output import OutputGrid, carried_pose
from toolkit.fusion.state import G
from toolkit.fusion.track_heading import start_heading


def estimate_stream(
    d: SensorData,
    imu_windows: Callable[[], Iterable[ImuWindow]],
    s: FilterSettings,
    *,
    t_end: float,
    period: float,
    result: EstimateResult,
    imu_gaps: FloatArray | None = None,
) -> Iterator[OutputChunk]:
    """Run the causal filter window by window (see the module docstring).

    ``d`` holds the GPS, compass and wheel arrays (its IMU arrays are not used);
    ``imu_windows`` opens a fresh pass over the IMU samples (called twice: once for the
    initial attitude, once for the run); ``t_end`` is the last IMU time and ``period`` the
    nominal IMU period. Output rows are yielded per window, so memory does not grow with the
    log; the accounting is written into ``result`` when the generator is exhausted.

    ``imu_gaps`` (K, 2): start and end (s) of the IMU gaps longer than
    :data:`~toolkit.fusion.epochs.MAX_BRIDGE_S` (the filter restarts across them). No pose row
    is written strictly inside one: with no IMU there, a row would be an extrapolation, not an
    estimate.
    """
    gaps = np.zeros((0, 2)) if imu_gaps is None else np.asarray(imu_gaps, dtype=np.float64)
    t_start, yaw0, heading_source = start_heading(d, s.track_min_distance_m)
    warnings = _heading_warnings(heading_source)
    epochs = filter_epochs(d, t_start, t_end, gaps)
    head = _first_second(d, imu_windows, t_start)
    attitude0, force_g = _initial_attitude(head, t_start, yaw0)
    warnings += _unsteady_start(force_g, heading_source)
    loop = EpochFilter(
        d,
        s,
        attitude0,
        t_start=t_start,
        t_end=t_end,
        heading_source=heading_source,
        epochs=epochs,
        period=period,
        accel_noise=AccelNoise(head.accel, period),
        warnings=warnings,
    )
    del head
    step = 1.0 / s.output_rate_hz
    grid = OutputGrid(d.t0_ns, t_start, step, int(np.floor((t_end - t_start) / step)), gaps)
    for wt, accel, gyro in imu_windows():
        seg = loop.window(wt, accel, gyro)
        if seg is None:
            continue
        chunk = grid.rows(seg.t, carried_pose(seg, s.lever_axle))
        if chunk is not None:
            yield chunk

    ukf = loop.ukf
    result.gated = dict(ukf.gated)
    result.accepted = dict(ukf.accepted)
    result.down_weighted = dict(ukf.down_weighted)
    result.imu_gaps_bridged = loop.n_bridged
    result.imu_gaps_restarted = loop.n_restart
    result.epochs = int(epochs.size)
    result.imu_samples = loop.n_imu
    result.heading_source = heading_source
    if grid.rows_in_gaps:
        warnings.append(
            f"no pose for {grid.rows_in_gaps * step:.1f} s in {gaps.shape[0]} IMU gap(s) longer "
            f"than {MAX_BRIDGE_S} s: nothing was measured there to estimate it from"
        )
    result.warnings = warnings
    result.reinitialised = loop.n_reinit


def _heading_warnings(heading_source: str) -> list[str]:
    """What the heading source leaves to warn about: no GPS at all, or no heading."""
    if heading_source == "local":
        return [
            "no GPS fix: dead-reckoning on the IMU and wheel speeds in a local frame whose "
            "origin is the first pose"
        ]
    if heading_source == "none":
        return ["no compass and the GPS track never runs straight far enough for a heading"]
    return []


def _first_second(
    d: SensorData, imu_windows: Callable[[], Iterable[ImuWindow]], t_start: float
) -> SensorData:
    """``d`` with the IMU samples from ``t_start`` to the end of the first window past
    ``t_start + 1`` s (at least the first second), which the initial attitude is taken from."""
    first_t: list[FloatArray] = []
    first_a: list[FloatArray] = []
    first_g: list[FloatArray] = []
    for wt, wa, wg in imu_windows():
        sel = wt >= t_start
        first_t.append(wt[sel])
        first_a.append(wa[sel])
        first_g.append(wg[sel])
        if wt.size and wt[-1] > t_start + 1.0:
            break
    return dataclasses.replace(
        d,
        imu_t=np.concatenate(first_t) if first_t else np.zeros(0),
        accel=np.concatenate(first_a) if first_a else np.zeros((0, 3)),
        gyro=np.concatenate(first_g) if first_g else np.zeros((0, 3)),
    )


#: The corrected mean specific force of the first second may differ from 1 g by this share
#: before the start is said to be unsteady: 0.05 g of unknown force tilts the level the
#: attitude is taken from by up to 2.9 deg. Measured: the simulator's starts (the sample, a
#: race, the calibration drive) and the real Husky log's are within 0.006 g of 1 g; the real
#: Ouster recording's (tests/data/real-lidar) is 1.073 g.
STEADY_START_G = 0.05


def _unsteady_start(force_g: float, heading_source: str) -> list[str]:
    """A warning when the first second's corrected specific force is not 1 g (its norm,
    ``force_g``, in g): the level the initial roll and pitch are taken from is then off."""
    if not np.isfinite(force_g) or abs(force_g - 1.0) <= STEADY_START_G:
        return []
    tilt = np.degrees(np.arcsin(min(1.0, abs(force_g - 1.0))))
    after = (
        "and without GPS nothing corrects them"
        if heading_source == "local"
        else "until the GPS velocities correct them"
    )
    return [
        f"the IMU's mean specific force over the first second is {force_g:.3f} g, not 1 g "
        "(after the wheels' acceleration and the turn): the vehicle was not steady or the "
        f"accelerometer is biased; the initial roll and pitch taken from it may be off by "
        f"{tilt:.0f} deg or more, {after}"
    ]


def _initial_attitude(d: SensorData, t_start: float, yaw: float) -> tuple[FloatArray, float]:
    """Roll and pitch from the mean specific force over the first second, corrected for the
    forward acceleration (wheel speed slope) and the centripetal term (yaw rate x speed); and
    that corrected force's norm in g (1 when the start was steady and the IMU unbiased;
    NaN without IMU samples)."""
    sel = (d.imu_t >= t_start) & (d.imu_t <= t_start + 1.0)
    if not sel.any():
        sel = d.imu_t >= t_start
    f = d.accel[sel].mean(axis=0)
    w = d.gyro[sel].mean(axis=0)
    ws = (d.wheel_t >= t_start) & (d.wheel_t <= t_start + 1.0)
    a_fwd, speed = 0.0, 0.0
    if ws.sum() >= 2:
        a_fwd = float(np.polyfit(d.wheel_t[ws], d.wheel_speed[ws], 1)[0])
        speed = float(d.wheel_speed[ws].mean())
    fx = f[0] - a_fwd
    fy = f[1] - w[2] * speed
    roll = float(np.arctan2(fy, f[2]))
    pitch = float(np.arctan2(-fx, np.hypot(fy, f[2])))
    force_g = float(np.sqrt(fx * fx + fy * fy + f[2] * f[2]) / G)
    return np.array([roll, pitch, yaw]), force_g


__all__ = ["estimate_stream"]

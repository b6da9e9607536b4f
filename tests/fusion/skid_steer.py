"""A small skid-steer robot's sensor streams, simulated for the dead-reckoning tests.

The robot of issue 27 (point 17): IMU at 50 Hz mounted level at base_link, wheel odometry
(forward speed) at 50 Hz, no GPS; about 84 m in 61 s at up to 2 m/s, turning about 275 deg
in all in arcs of up to ~0.9 rad/s. The toolkit's simulator (:mod:`toolkit.sim`) is a
Touareg-sized full-car model at race speeds, so the streams are generated here from a
kinematic truth:

- truth at 1 kHz: speed ``v(t)`` and yaw rate ``w(t)`` (smooth profiles), small terrain roll
  and pitch (a few degrees, ~0.3-1 Hz), base_link velocity ``R (v, 0, 0)`` in ENU;
- IMU: the mean over each 20 ms of the true specific force ``R^T (a + (0, 0, g))`` and body
  rate ``(R^T R')^v``, stamped at the end of the interval it averages (as the estimator
  reads it), plus a constant bias (accelerometer 0.2 m/s^2, gyro 0.005 rad/s per axis,
  1 sigma: the turn-on offsets of a consumer MEMS IMU, e.g. the Bosch BMI088's datasheet
  gives +-20 mg and +-1 deg/s), white noise (accelerometer 0.02 m/s^2, gyro 0.002 rad/s
  per sample: noise densities of ~0.2 mg/sqrt(Hz) and ~0.015 deg/s/sqrt(Hz) over a 25 Hz
  band) and the chassis vibration of a skid-steer robot, aliased to white noise at 50 Hz
  (0.9 m/s^2 horizontal and 1.5 vertical, about 0.1 g; 0.03 rad/s);
- wheels: the forward speed read ``(1 + k) v + e`` with a scale error ``k`` (2 % 1 sigma)
  and noise ``e`` whose 1 sigma grows with the yaw rate, ``0.02 + 0.4 |w|`` m/s: a
  skid-steer robot turns by slipping its tracks, so its wheel speeds stop measuring the
  ground speed in a turn.

The "plain integral" is what a reader does by hand: heading the integral of the gyro's z
rate, position the integral of the wheel speed along it (:func:`plain_integral`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.fusion.estimator_io import SensorData
from toolkit.geometry.rotations import FloatArray, euler_to_rot

TRUTH_HZ = 1000
IMU_HZ = 50
WHEEL_HZ = 50
DURATION_S = 61.0
G = 9.80665


@dataclass(frozen=True)
class SkidSteerRun:
    """Sensor streams and truth of one simulated drive (times in s from the log start)."""

    data: SensorData  # wheels only: no GPS, compass or IMU attitude
    imu_t: FloatArray
    accel: FloatArray
    gyro: FloatArray
    truth_t: FloatArray
    truth_xy: FloatArray  # base_link, ENU
    truth_yaw: FloatArray
    distance_m: float
    turn_deg: float
    wheel_scale: float


def _smooth_steps(t: FloatArray, times: FloatArray, values: FloatArray, tau: float) -> FloatArray:
    """A piecewise-constant profile (``values[i]`` from ``times[i]``) with its steps smoothed
    by a raised cosine ``tau`` seconds long (so acceleration and jerk stay finite)."""
    out = np.full_like(t, values[0])
    for k in range(1, times.size):
        ramp = np.clip((t - times[k]) / tau, 0.0, 1.0)
        out += (values[k] - values[k - 1]) * 0.5 * (1.0 - np.cos(np.pi * ramp))
    return out


def _profiles(rng: np.random.Generator, t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Speed (m/s) and yaw rate (rad/s) over ``t``: a start from rest, cruising at 1.2-2 m/s,
    nine turns of 15-50 deg at 0.5-0.9 rad/s (slower in the turn), a stop at the end."""
    n_turn = 9
    # Turn angles scaled to ~275 deg in all, alternating mostly, at random times.
    angles = rng.uniform(15.0, 50.0, n_turn)
    angles *= 275.0 / angles.sum()
    signs = np.where(rng.random(n_turn) < 0.7, 1.0, -1.0) * np.where(
        np.arange(n_turn) % 2 == 0, 1.0, -1.0
    )
    rates = rng.uniform(0.5, 0.9, n_turn)
    starts = np.sort(rng.uniform(5.0, DURATION_S - 6.0, n_turn))
    for k in range(1, n_turn):  # at least 2.5 s apart
        starts[k] = max(starts[k], starts[k - 1] + 2.5 + np.radians(angles[k - 1]) / rates[k - 1])
    starts = np.minimum(starts, DURATION_S - 4.0)
    w = np.zeros_like(t)
    slow = np.zeros_like(t)
    tau = 0.4
    for a, r, s, sg in zip(angles, rates, starts, signs, strict=True):
        dur = np.radians(a) / r  # a raised-cosine ramp of tau at each end keeps the angle
        w += (
            sg
            * r
            * (
                _smooth_steps(t, np.array([0.0, s]), np.array([0.0, 1.0]), tau)
                - _smooth_steps(t, np.array([0.0, s + dur]), np.array([0.0, 1.0]), tau)
            )
        )
        slow = np.maximum(
            slow,
            _smooth_steps(t, np.array([0.0, s - 0.5]), np.array([0.0, 1.0]), 0.8)
            - _smooth_steps(t, np.array([0.0, s + dur]), np.array([0.0, 1.0]), 0.8),
        )
    cruise_t = np.concatenate([[0.0], np.sort(rng.uniform(3.0, DURATION_S - 5.0, 6))])
    cruise_v = rng.uniform(1.2, 2.0, cruise_t.size)
    cruise_v[0] = 0.0
    cruise_t[0], cruise_v[0] = 0.0, 0.0
    v = _smooth_steps(t, np.r_[0.0, 0.5, cruise_t[1:]], np.r_[0.0, 1.6, cruise_v[1:]], 2.0)
    v *= 1.0 - 0.45 * slow  # slower in the turns
    v *= _smooth_steps(t, np.array([0.0, DURATION_S - 3.0]), np.array([1.0, 0.0]), 2.0)
    return v, w


def simulate(seed: int) -> SkidSteerRun:
    """One drive of the small skid-steer robot (module docstring)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / TRUTH_HZ
    t = np.arange(int(DURATION_S * TRUTH_HZ) + 1) * dt
    v, w = _profiles(rng, t)
    yaw = np.cumsum(w) * dt
    # Terrain roll and pitch: a few sinusoids each, up to ~3 deg.
    roll = np.zeros_like(t)
    pitch = np.zeros_like(t)
    for ang in (roll, pitch):
        for _ in range(3):
            amp = np.radians(rng.uniform(0.3, 1.0))
            f = rng.uniform(0.1, 1.0)
            ang += amp * np.sin(2.0 * np.pi * f * t + rng.uniform(0.0, 2.0 * np.pi))
    rot = euler_to_rot(np.stack([roll, pitch, yaw], axis=1))
    vel = rot[:, :, 0] * v[:, None]  # ENU velocity of base_link: R (v, 0, 0)
    pos = np.cumsum(vel, axis=0) * dt
    acc = np.gradient(vel, dt, axis=0)
    f_body = np.einsum("nji,nj->ni", rot, acc + np.array([0.0, 0.0, G]))
    # Body rate: R^T R' = [w]x.
    rdot = np.gradient(rot, dt, axis=0)
    skew = np.einsum("nji,njk->nik", rot, rdot)
    w_body = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)

    # IMU: means over each 20 ms, stamped at the end of it.
    per = TRUTH_HZ // IMU_HZ
    n_imu = (t.size - 1) // per
    blocks = slice(1, 1 + n_imu * per)
    imu_t = t[per : (n_imu + 1) * per : per]
    accel = f_body[blocks].reshape(n_imu, per, 3).mean(axis=1)
    gyro = w_body[blocks].reshape(n_imu, per, 3).mean(axis=1)
    accel += rng.normal(0.0, 0.2, 3)
    gyro += rng.normal(0.0, 0.005, 3)
    accel += rng.normal(0.0, 0.02, accel.shape)
    gyro += rng.normal(0.0, 0.002, gyro.shape)
    accel += rng.normal(0.0, 1.0, accel.shape) * np.array([0.9, 0.9, 1.5])
    gyro += rng.normal(0.0, 0.03, gyro.shape)

    # Wheels: (1 + k) v + e, e growing with the yaw rate (track slip in turns).
    wper = TRUTH_HZ // WHEEL_HZ
    wheel_idx = np.arange(0, t.size, wper)
    k = float(rng.normal(0.0, 0.02))
    sigma = 0.02 + 0.4 * np.abs(w[wheel_idx])
    wheel_speed = (1.0 + k) * v[wheel_idx] + rng.normal(0.0, 1.0, wheel_idx.size) * sigma

    empty = np.zeros(0)
    data = SensorData(
        t0_ns=0,
        imu_t=imu_t,
        accel=accel,
        gyro=gyro,
        gps_t=empty,
        gps_enu=np.zeros((0, 3)),
        gps_var=np.zeros((0, 3)),
        head_t=empty,
        head_yaw=empty,
        head_var=empty,
        wheel_t=t[wheel_idx],
        wheel_speed=wheel_speed,
    )
    return SkidSteerRun(
        data=data,
        imu_t=imu_t,
        accel=accel,
        gyro=gyro,
        truth_t=t,
        truth_xy=pos[:, :2],
        truth_yaw=yaw,
        distance_m=float(np.sum(np.abs(v)) * dt),
        turn_deg=float(np.degrees(np.sum(np.abs(w)) * dt)),
        wheel_scale=k,
    )


def plain_integral(run: SkidSteerRun, t_from: float) -> tuple[FloatArray, FloatArray]:
    """The hand-made dead reckoning from ``t_from`` at the IMU's rate, in the frame of the
    first pose (origin 0, yaw 0): ``yaw = int gyro_z dt``, ``p = int u (cos yaw, sin yaw)
    dt`` with ``u`` the wheel speed. Returns (t (N,), xy (N, 2))."""
    keep = run.imu_t > t_from
    t = run.imu_t[keep]
    dt = np.diff(t, prepend=t_from)
    yaw = np.cumsum(run.gyro[keep, 2] * dt)
    u = np.interp(t, run.data.wheel_t, run.data.wheel_speed)
    xy = np.cumsum(np.stack([u * np.cos(yaw), u * np.sin(yaw)], axis=1) * dt[:, None], axis=0)
    return t, xy

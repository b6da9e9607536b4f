"""The causal pose estimator: sensor arrays in, 100 Hz base_link pose out.

Filter steps ("epochs") fall on every valid GPS fix and every compass reading, with filler
epochs so that no step is longer than :data:`MAX_STEP_S` (GPS dropouts coast on IMU, wheels
and the non-holonomic constraint). Between epochs the IMU is pre-integrated sample by sample
(the one Python loop per IMU sample); the same increments carry the posterior mean of the
last epoch forward to every IMU sample, which gives the output between filter steps without
using anything measured later. At each epoch: predict, then one joint update with whatever
was measured then (GPS, compass yaw, the IMU's own roll and pitch, wheel speed, and the
non-holonomic constraint), each sensor gated on its own innovation
(:meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`), except the wheels in odometry dead
reckoning (below).

Heading: from the compass when there is one; else from the GPS track once a run of fixes
lies on a straight line long enough for its direction (:func:`_start`), whatever the speed,
and afterwards the direction of the latest straight stretch of the track, carried from the
stretch's mean time to now by the turn the filter made since (:class:`_YawHistory`), is a yaw
measurement at every fix (``gps_track``, :func:`_track_headings`, variance
``2 sigma_h^2 / L^2 +`` :data:`TRACK_YAW_FLOOR_RAD` ``^2``, gated like the compass).
An IMU that reports its orientation contributes its roll and pitch (gravity-referenced) as
measurements; its yaw is not used as a heading: on the one real log here (a Clearpath Husky)
its magnetic yaw differs from the GPS track by -90 to -147 deg depending on the direction of
travel (an uncalibrated magnetometer), which no fixed offset absorbs.

No GPS fix at all: the filter dead-reckons on IMU, wheel speeds and the non-holonomic
constraint in a local frame whose origin and zero yaw are the first pose (heading source
``local``), starting with the wheel speeds. How, is the vehicle configuration's choice
(``[pose] dead_reckoning``):

- ``inertial`` (default): wheel speed and NHC update every state, so the accelerometer can
  correct the heading and the z gyro bias (the centripetal ``v w_z`` against the gyro, the
  direction of the integrated velocity against the body axis). That is real information on a
  fast vehicle with a clean IMU: simulated seed 101 without GPS ends 110 m from the truth
  after 2.9 km, where the gyro's own integral (its 0.002 rad/s bias never learned) ends 1494 m
  away.
- ``odometry``: the updates are conditioned on position, yaw, z gyro bias and wheel scale
  (:data:`~toolkit.fusion.state.DEAD_RECKONING_GIVEN`, :meth:`~toolkit.fusion.ukf.PoseUKF.
  update_joint`): the heading is the gyro's integral and the position the integral of the
  velocity the wheels and NHC keep on the body axes, the UKF still giving roll, pitch and a
  3-D path; robot_localization's odom frame on a ground robot does the same. For a slow robot
  with a MEMS IMU, where a lateral accelerometer error of 0.05 m/s^2 equals a 3 deg/s yaw-rate
  error at 1 m/s: the Husky log without its GPS ends 3.6 m (1.0 %) from its wheel + gyro
  integral this way and 36 m (10 %) with ``inertial``, whose corrections turned its yaw by
  17.5 deg and moved its position 306 m in all over a 359 m drive.
  The velocity's process noise is, in this mode, at least the accelerometer's own noise as
  measured on the log (:class:`_AccelNoise`, :func:`vibration_q`): with the configured
  Stanley-class ``accel_noise_mps2`` alone, the filter takes the integral of a vibrating
  MEMS accelerometer for a better velocity than the wheels', gates them and drifts (a
  simulated skid-steer robot, ``tests/fusion/skid_steer.py``: 140-510 of 610 wheel updates
  gated and 13-225 m from the wheel + gyro integral after 80-90 m; with it 16-32 gated,
  the slipping readings of its turns, and 0.5-1.9 m).
  Nor is a wheel reading rejected in this mode: beyond its gate it is down-weighted, its
  variance inflated until its innovation is at the gate (``robust``,
  :meth:`~toolkit.fusion.ukf.PoseUKF.update_joint`), and counted (``down_weighted``). The
  wheels are the only velocity reference here: a rejected reading leaves the velocity to
  the accelerometer's integral, worse than a slipping track's reading, while the plain
  wheel + gyro integral uses every reading. The simulated robot then has none of 610
  gated (18-27 down-weighted, seeds 1-8) and ends 0.5-1.8 m from that integral.

Recovery: after ``reinit_after_gated_fixes`` GPS fixes in a row are gated, position and
velocity are taken from the GPS again (:func:`_reinitialise`), counted and warned about, so a
filter that has drifted away is never locked out by its own gate.

IMU gaps: a sample interval longer than 1.5 nominal periods is a gap. Gaps up to
:data:`MAX_BRIDGE_S` are bridged (the next sample's reading is held across the gap); longer
ones restart the filter: the gap is crossed at constant velocity and attitude, and the
covariance of position, velocity and attitude is raised to at least its initial value at
every epoch in the gap (:meth:`~toolkit.fusion.ukf.PoseUKF.restart`, which says how and why).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

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
from toolkit.fusion.process import ImuIncrement, NoiseModel
from toolkit.fusion.rotations import FloatArray, euler_rates, euler_to_rot, rot_to_euler, wrap_angle
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
from toolkit.fusion.ukf import PoseUKF

#: Longest filter step, s.
MAX_STEP_S = 0.1
#: Longest IMU gap bridged; a longer one restarts the filter, s.
MAX_BRIDGE_S = 0.5
#: Longest IMU gap crossed at constant velocity and attitude, s. After a longer one (a
#: recorder paused, a sensor unplugged) where the vehicle went is unknown: the crossing
#: stops after this long (so neither the motion nor the process noise is integrated over a
#: gap of hours, which would only make up a position and overflow the covariance), and the
#: first GPS fix after the gap re-initialises position and velocity.
MAX_CROSS_S = 2.0
#: Longest time a run of fixes may span to give the GPS-track heading, s.
TRACK_MAX_SPAN_S = 30.0
#: Largest RMS distance of a run of fixes from their line, in fix sigmas, for a track heading.
TRACK_STRAIGHT_SIGMAS = 1.5
#: 1 sigma added to a GPS-track yaw: the direction of travel is not exactly the heading (the
#: slight crabbing of a skid-steer robot, what is left of a turn in a "straight" run), rad.
TRACK_YAW_FLOOR_RAD = 0.05
#: Time constant of the running estimate of the accelerometer's noise in odometry dead
#: reckoning (:class:`_AccelNoise`), s: long against the 20-100 Hz vibration it measures
#: (hundreds of samples), short against a change of terrain or speed.
ACCEL_NOISE_TAU_S = 2.0


class _AccelNoise:
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
    (3,), ``N_i^2`` of :class:`_AccelNoise`, body axes) exceeds the configured white noise
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


def _initial_attitude(d: SensorData, t_start: float, yaw: float) -> FloatArray:
    """Roll and pitch from the mean specific force over the first second, corrected for the
    forward acceleration (wheel speed slope) and the centripetal term (yaw rate x speed)."""
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
    return np.array([roll, pitch, yaw])


def _track_end(d: SensorData, i: int, track_min_distance_m: float) -> int | None:
    """The first fix ``j > i`` at least ``D = max(track_min_distance_m, 10 sigma_h)`` from
    fix ``i`` and at most :data:`TRACK_MAX_SPAN_S` later, or None. (Only that window is
    searched, so a vehicle parked for an hour costs time linear in the fixes.)"""
    sigma_h = float(np.sqrt(0.5 * (d.gps_var[i, 0] + d.gps_var[i, 1])))
    reach = max(track_min_distance_m, 10.0 * sigma_h)
    hi = int(np.searchsorted(d.gps_t, d.gps_t[i] + TRACK_MAX_SPAN_S, side="right"))
    dist = np.hypot(*(d.gps_enu[i + 1 : hi, :2] - d.gps_enu[i, :2]).T)
    far = np.flatnonzero(dist >= reach)
    return i + 1 + int(far[0]) if far.size else None


def _track_line(d: SensorData, i: int, j: int) -> tuple[float | None, float]:
    """Direction (rad, ENU yaw) of fixes ``i..j`` if they lie on a straight line, and its
    variance ``2 sigma_h^2 / L^2`` (``L`` their span); (None, inf) if they do not.

    The line is the principal axis of the fixes' scatter, pointed from ``p_i`` to ``p_j``;
    they lie on it when the RMS of their distances to it is at most
    :data:`TRACK_STRAIGHT_SIGMAS` ``sigma_h`` (a turn bends them off it, and a chord across a
    turn gives the heading of no point of it).
    """
    pts = d.gps_enu[i : j + 1, :2]
    sigma_h = float(np.sqrt(0.5 * (d.gps_var[i : j + 1, 0] + d.gps_var[i : j + 1, 1])).mean())
    centred = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    chord = pts[-1] - pts[0]
    axis = vt[0] if vt[0] @ chord > 0 else -vt[0]
    normal = np.array([-axis[1], axis[0]])
    if float(np.sqrt(np.mean((centred @ normal) ** 2))) > TRACK_STRAIGHT_SIGMAS * sigma_h:
        return None, np.inf
    span = float(np.hypot(chord[0], chord[1]))
    return float(np.arctan2(axis[1], axis[0])), 2.0 * sigma_h**2 / span**2


def _track_headings(
    d: SensorData, track_min_distance_m: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per fix ``k``, the GPS track's direction over the latest straight run of fixes ending
    at ``k`` (:func:`_track_line` of ``i..k``, ``i`` the last fix at least ``D`` back), its
    variance and the run's mean time (s); NaN where there is none. Causal: only fixes up to
    ``k``.

    The principal axis of a run is the direction of travel near the run's centroid, that is
    at its mean time, not at fix ``k``: on a gentle curve (which still passes the
    straightness test) the two differ by the turn made since. The filter therefore compares
    the track with its own yaw at the mean time (see :func:`_delayed_yaw`).
    """
    n = d.gps_t.size
    yaw = np.full(n, np.nan)
    var = np.full(n, np.nan)
    t_mid = np.full(n, np.nan)
    xy = d.gps_enu[:, :2]
    for k in range(1, n):
        sigma_h = float(np.sqrt(0.5 * (d.gps_var[k, 0] + d.gps_var[k, 1])))
        reach = max(track_min_distance_m, 10.0 * sigma_h)
        lo = int(np.searchsorted(d.gps_t, d.gps_t[k] - TRACK_MAX_SPAN_S))
        back = np.flatnonzero(np.hypot(*(xy[lo:k] - xy[k]).T) >= reach)
        if back.size == 0:
            continue
        i = lo + int(back[-1])
        y, v = _track_line(d, i, k)
        if y is not None:
            yaw[k], var[k], t_mid[k] = y, v, float(d.gps_t[i : k + 1].mean())
    return yaw, var, t_mid


class _YawHistory:
    """The filter's posterior yaw at recent epochs (unwrapped), to carry a measurement of
    the yaw at an earlier time to now: ``z_now = z_then + (yaw_now - yaw_then)``, the turn
    made since as the filter itself integrated it (gyro and corrections). Holds at most
    :data:`TRACK_MAX_SPAN_S` of history, so memory is bounded."""

    def __init__(self) -> None:
        self._t: list[float] = []
        self._yaw: list[float] = []

    def add(self, t: float, yaw: float) -> None:
        if self._yaw:
            yaw = self._yaw[-1] + float(wrap_angle(np.array(yaw - self._yaw[-1])))
        self._t.append(t)
        self._yaw.append(yaw)
        if len(self._t) > 64 and self._t[0] < t - TRACK_MAX_SPAN_S - 1.0:
            cut = int(np.searchsorted(self._t, t - TRACK_MAX_SPAN_S - 1.0))
            del self._t[:cut], self._yaw[:cut]

    def turn_since(self, t_then: float, yaw_now: float) -> float | None:
        """``yaw_now - yaw(t_then)`` wrapped to [-pi, pi), or None before the history."""
        if not self._t or t_then < self._t[0]:
            return None
        then = float(np.interp(t_then, self._t, self._yaw))
        return float(wrap_angle(np.array(yaw_now - then)))


def _start(d: SensorData, track_min_distance_m: float) -> tuple[float, float, str]:
    """Start time, initial yaw and where the heading comes from.

    With a compass: its first reading at or after the first fix. Without: the GPS track,
    from the first run of fixes ``i..j`` that spans a straight line long enough for its
    direction to be good to a few degrees at any speed (a robot at 1 m/s included):

    - ``|p_j - p_i| >= D = max(track_min_distance_m, 10 sigma_h)`` (``sigma_h`` the fixes'
      horizontal 1 sigma), within :data:`TRACK_MAX_SPAN_S`;
    - the fixes fit a line: the RMS of their distances to the least-squares line through
      them (principal axis of their scatter) is at most :data:`TRACK_STRAIGHT_SIGMAS`
      ``sigma_h`` (a turn bends them off it; a chord across a turn would give the heading
      of no point of it).

    The heading is the line's direction, pointing from ``p_i`` to ``p_j``; the filter starts
    at ``t_j``. Its error, about ``sqrt(2) sigma_h / D`` rad, is within the initial yaw
    uncertainty (0.3 rad) and the GPS refines it as the vehicle moves.
    """
    if d.gps_t.size == 0:
        # No GPS: a local frame whose origin and yaw 0 are the first pose, once the wheels
        # (the only speed reference left) have started.
        t0 = float(d.wheel_t[0]) if d.wheel_t.size else 0.0
        return t0, 0.0, "local"
    t_fix = float(d.gps_t[0])
    if d.head_t.size:
        i = int(np.searchsorted(d.head_t, t_fix))
        if i < d.head_t.size:
            return max(t_fix, float(d.head_t[i])), float(d.head_yaw[i]), "compass"
    for i in range(d.gps_t.size):
        j = _track_end(d, i, track_min_distance_m)
        if j is None:
            continue
        yaw, _ = _track_line(d, i, j)
        if yaw is not None:
            return float(d.gps_t[j]), yaw, "gps_track"
    return t_fix, 0.0, "none"


def _inside(x: FloatArray, gaps: FloatArray) -> np.ndarray:
    """Whether each time of ``x`` lies strictly inside one of the sorted, disjoint
    ``gaps`` (K, 2) intervals."""
    if gaps.shape[0] == 0:
        return np.zeros(np.shape(x), dtype=bool)
    i = np.searchsorted(gaps[:, 0], x, side="right") - 1
    ok = i >= 0
    j = np.maximum(i, 0)
    return np.asarray(ok & (x > gaps[j, 0]) & (x < gaps[j, 1]), dtype=bool)


def _epochs(d: SensorData, t_start: float, t_end: float, imu_gaps: FloatArray) -> FloatArray:
    """Filter step times: every GPS fix and compass reading, and fillers so that no step is
    longer than :data:`MAX_STEP_S` -- except inside the IMU gaps the filter restarts
    across, where there is nothing to step on. So the count grows with the data, never
    with the time a log spans (a recorder paused for a year adds two epochs, not 300 M)."""
    t = np.union1d(d.gps_t, d.head_t)
    t = t[(t > t_start) & (t <= t_end)]
    edges = imu_gaps.ravel()
    edges = edges[(edges > t_start) & (edges <= t_end)]
    t = np.unique(np.concatenate([[t_start], t, edges, [t_end]]))
    gaps = np.diff(t)
    n_fill = np.maximum(np.ceil(gaps / MAX_STEP_S).astype(int) - 1, 0)
    n_fill[_inside(0.5 * (t[:-1] + t[1:]), imu_gaps)] = 0
    if n_fill.any():
        fills = [
            t[i] + gaps[i] * np.arange(1, n + 1) / (n + 1) for i, n in enumerate(n_fill) if n > 0
        ]
        t = np.union1d(t, np.concatenate(fills))
    return np.asarray(t[1:], dtype=np.float64)


def _reinitialise(
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


ImuWindow = tuple[FloatArray, FloatArray, FloatArray]
"""One window of IMU samples in time order: (t (N,), accel (N, 3), gyro (N, 3))."""

OutputChunk = tuple[np.ndarray, dict[str, FloatArray]]
"""Output rows of one window: (t_ns (M,), pose columns)."""


def _grid_outside(
    t0: float, step: float, m_lo: int, m_hi: int, gaps: FloatArray
) -> tuple[FloatArray, int]:
    """The output times ``t0 + step m`` for ``m_lo <= m <= m_hi`` that are not strictly
    inside a gap, and how many were left out; nothing is allocated for the times left out."""
    pieces: list[np.ndarray] = []
    m = m_lo
    lo_t, hi_t = t0 + step * m_lo, t0 + step * m_hi
    for a, b in gaps[(gaps[:, 1] > lo_t) & (gaps[:, 0] < hi_t)]:
        m_a = min(int(np.floor((a - t0) / step)), m_hi)  # the last time at or before a
        if m_a >= m:
            pieces.append(np.arange(m, m_a + 1))
        m = max(m, int(np.ceil((b - t0) / step)))  # the first at or after b
    if m <= m_hi:
        pieces.append(np.arange(m, m_hi + 1))
    ms = np.concatenate(pieces) if pieces else np.zeros(0, dtype=np.int64)
    return np.asarray(t0 + step * ms, dtype=np.float64), (m_hi - m_lo + 1) - int(ms.size)


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

    ``imu_gaps`` (K, 2): start and end (s) of the IMU gaps longer than :data:`MAX_BRIDGE_S`
    (the filter restarts across them). No pose row is written strictly inside one: with no
    IMU there, a row would be an extrapolation, not an estimate.
    """
    gaps = np.zeros((0, 2)) if imu_gaps is None else np.asarray(imu_gaps, dtype=np.float64)
    t_start, yaw0, heading_source = _start(d, s.track_min_distance_m)
    warnings: list[str] = []
    if heading_source == "local":
        warnings.append(
            "no GPS fix: dead-reckoning on the IMU and wheel speeds in a local frame whose "
            "origin is the first pose"
        )
    elif heading_source == "none":
        warnings.append("no compass and the GPS track never runs straight far enough for a heading")
    epochs = _epochs(d, t_start, t_end, gaps)
    if heading_source == "compass":
        track_yaw = track_var = track_t = np.full(d.gps_t.size, np.nan)
    else:
        track_yaw, track_var, track_t = _track_headings(d, s.track_min_distance_m)
    yaw_history = _YawHistory()

    # Initial attitude from the first second of IMU after the start.
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
    head = SensorData(
        t0_ns=d.t0_ns,
        imu_t=np.concatenate(first_t) if first_t else np.zeros(0),
        accel=np.concatenate(first_a) if first_a else np.zeros((0, 3)),
        gyro=np.concatenate(first_g) if first_g else np.zeros((0, 3)),
        gps_t=d.gps_t,
        gps_enu=d.gps_enu,
        gps_var=d.gps_var,
        head_t=d.head_t,
        head_yaw=d.head_yaw,
        head_var=d.head_var,
        wheel_t=d.wheel_t,
        wheel_speed=d.wheel_speed,
    )
    att0 = _initial_attitude(head, t_start, yaw0)
    accel_noise = _AccelNoise(head.accel, period)
    del head, first_t, first_a, first_g

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
    P0 = np.diag(p0)
    ukf = PoseUKF(x0, P0, s.noise, alpha=s.alpha, beta=s.beta, kappa=s.kappa)

    hx_yaw = yaw_model
    hx_gps = gps_model(s.lever_gps)
    wheel_var = np.array([[s.wheel_var]])
    nhc_cov = np.eye(2) * NHC_STD_MPS**2
    R_heading_idx = {float(t): i for i, t in enumerate(d.head_t.tolist())}
    gps_idx = {float(t): i for i, t in enumerate(d.gps_t.tolist())}
    zero2 = np.zeros(2)
    # Odometry dead reckoning: every update conditioned on what it must not move (above).
    given = (
        DEAD_RECKONING_GIVEN if heading_source == "local" and s.dead_reckoning == "odometry" else ()
    )
    step = 1.0 / s.output_rate_hz
    n_out_total = int(np.floor((t_end - t_start) / step))

    post_k = ukf.x.copy()  # posterior at the start of the current epoch interval
    inc = ImuIncrement(ukf.x[BA].copy(), ukf.x[BG].copy())
    restart_pending = False
    lost_track_s = 0.0  # the longest gap not crossed since the last fix
    prev_imu_t: float | None = None
    prev_bound = t_start  # the last segment end handled
    prev_row: dict[str, float] | None = None  # last segment's values, for interpolation
    first_seg_t: float | None = None
    n_bridged = n_restart = n_imu = n_reinit = rows_in_gaps = 0
    gps_streak = 0  # consecutive gated fixes
    last_att = -1  # index of the last IMU attitude used
    m_next = 1  # next output index (t_out = t_start + step * m)

    for wt, accel, gyro in imu_windows():
        if wt.size == 0:
            continue
        w_prev = (wt[0] - period) if prev_imu_t is None else prev_imu_t
        imu_dt = np.diff(wt, prepend=w_prev)
        prev_imu_t = float(wt[-1])
        # Odometry dead reckoning: the accelerometer's own noise, measured (_AccelNoise).
        acc_density2 = accel_noise.window(accel) if given else None
        after = wt > t_start
        gap_w = (imu_dt > 1.5 * period) & after
        n_restart += int((imu_dt[gap_w] > MAX_BRIDGE_S).sum())
        n_bridged += int(gap_w.sum() - (imu_dt[gap_w] > MAX_BRIDGE_S).sum())
        n_imu += int(np.count_nonzero(after & (wt <= t_end)))
        t_hi = float(wt[-1])
        if t_hi <= t_start:
            continue
        lo = prev_bound
        ep_w = epochs[(epochs > lo) & (epochs <= t_hi)]
        bounds = np.union1d(wt[(wt > lo) & (wt <= t_end)], ep_w)
        if bounds.size == 0:
            continue
        seg_dt = np.diff(bounds, prepend=lo)
        seg_imu = np.searchsorted(wt, bounds, side="left")
        seg_is_epoch = np.isin(bounds, ep_w)
        gap_len = imu_dt[seg_imu]
        restart_seg = (gap_len > 1.5 * period) & (gap_len > MAX_BRIDGE_S)
        n_seg = bounds.size
        seg_tau = np.empty(n_seg)
        seg_dR = np.empty((n_seg, 3, 3))
        seg_dv = np.empty((n_seg, 3))
        seg_dp = np.empty((n_seg, 3))
        seg_w = np.empty((n_seg, 3))
        seg_base = np.empty((n_seg, DIM_X))
        seg_post = np.empty((n_seg, DIM_X))
        for j in range(n_seg):
            i = int(seg_imu[j])
            seg_base[j] = post_k
            if restart_seg[j]:
                f_hold = inc.rot_inc.T @ euler_to_rot(post_k[ATT]).T @ (-GRAVITY) + inc.ba0
                inc.add(f_hold, inc.bg0, min(float(seg_dt[j]), MAX_CROSS_S))
                restart_pending = True
                if seg_dt[j] > MAX_CROSS_S:
                    lost_track_s = max(lost_track_s, float(seg_dt[j]))
            else:
                inc.add(accel[i], gyro[i], float(seg_dt[j]))
            seg_tau[j] = inc.T
            seg_dR[j] = inc.rot_inc
            seg_dv[j] = inc.dv
            seg_dp[j] = inc.dp
            seg_w[j] = gyro[min(i, gyro.shape[0] - 1)] - inc.bg0
            if not seg_is_epoch[j]:
                continue
            t = float(bounds[j])
            if acc_density2 is None:
                ukf.predict(inc)
            else:
                # The wheels are the velocity reference here: a filter that took the
                # accelerometer for cleaner than it is would prefer its own integral of a
                # vibrating MEMS accelerometer to them, gate them, and drift (issue 27, 17).
                a2 = acc_density2[min(i, acc_density2.shape[0] - 1)]
                ukf.predict(inc, vibration_q(post_k[ATT], a2, s.noise.accel, inc.T))
            if restart_pending:
                ukf.restart(P0)
                restart_pending = False
            w_now = seg_w[j]
            # Everything measured at this epoch updates from one sigma-point draw, each
            # sensor gated on its own innovation (PoseUKF.update_joint).
            blocks: list[Measurement] = []
            gi = gps_idx.get(t)
            if gi is not None:
                blocks.append(
                    Measurement("gps", d.gps_enu[gi], np.diag(d.gps_var[gi]), hx_gps, s.gate_gps)
                )
            hi = R_heading_idx.get(t)
            if hi is not None:
                blocks.append(
                    Measurement(
                        "heading",
                        d.head_yaw[hi : hi + 1],
                        d.head_var[hi : hi + 1, None],
                        hx_yaw,
                        s.gate_heading,
                        angle_mean,
                        angle_residual,
                    )
                )
            ti = gi if gi is not None and np.isfinite(track_yaw[gi]) else None
            turn = (
                None
                if ti is None
                else yaw_history.turn_since(float(track_t[ti]), float(ukf.x[YAW]))
            )
            if ti is not None and turn is not None:
                # No compass: the direction of the latest straight GPS track, which is the
                # yaw at the run's mean time, carried to now by the turn made since.
                blocks.append(
                    Measurement(
                        "gps_track",
                        wrap_angle(track_yaw[ti : ti + 1] + turn),
                        np.array([[track_var[ti] + TRACK_YAW_FLOOR_RAD**2]]),
                        hx_yaw,
                        s.gate_heading,
                        angle_mean,
                        angle_residual,
                    )
                )
            ai = int(np.searchsorted(d.att_t, t, side="right")) - 1
            if ai > last_att and t - d.att_t[ai] <= MAX_STEP_S:
                # The latest orientation the IMU reported, once: its roll and pitch (gravity-
                # referenced); its yaw is not used as a heading (see the module docstring).
                last_att = ai
                blocks.append(
                    Measurement(
                        "imu_attitude",
                        d.att_rpy[ai, :2],
                        np.diag(d.att_var[ai, :2]),
                        roll_pitch_model,
                        s.gate_attitude,
                        angle_mean,
                        angle_residual,
                    )
                )
            if d.wheel_t.size and d.wheel_t[0] <= t <= d.wheel_t[-1]:
                speed = float(np.interp(t, d.wheel_t, d.wheel_speed))
                blocks.append(
                    Measurement(
                        "wheels",
                        np.array([speed]),
                        wheel_var,
                        wheel_model(w_now, s.lever_axle),
                        s.gate_wheels,
                        # Odometry dead reckoning: the wheels are the only velocity
                        # reference, so an outlier is down-weighted, never dropped.
                        robust=bool(given),
                    )
                )
            blocks.append(
                Measurement("nhc", zero2, nhc_cov, nhc_model(w_now, s.lever_axle), NHC_GATE_CHI2)
            )
            if gi is not None and lost_track_s > 0.0:
                # After a gap too long to cross, the first fix says where the vehicle is.
                _reinitialise(ukf, d, gi, t, 1, s, P0)
                warnings.append(
                    f"IMU gap of {lost_track_s:.1f} s (longer than {MAX_CROSS_S} s) before t = "
                    f"{t:.1f} s: position and velocity re-initialised from the GPS"
                )
                n_reinit += 1
                lost_track_s = 0.0
            flags = ukf.update_joint(blocks, given=given)
            if gi is not None:
                gps_streak = 0 if flags[0] else gps_streak + 1
                if s.reinit_after_gated_fixes and gps_streak >= s.reinit_after_gated_fixes:
                    _reinitialise(ukf, d, gi, t, gps_streak, s, P0)
                    warnings.append(
                        f"{gps_streak} GPS fixes in a row gated at t = {t:.1f} s: position "
                        "and velocity re-initialised from the GPS"
                    )
                    n_reinit += 1
                    gps_streak = 0
            post_k = ukf.x.copy()
            yaw_history.add(t, float(post_k[YAW]))
            seg_post[j] = post_k
            inc = ImuIncrement(ukf.x[BA].copy(), ukf.x[BG].copy())
        prev_bound = float(bounds[-1])

        # The mean carried from each epoch's posterior to every segment end (vectorised).
        ep_seg = np.flatnonzero(seg_is_epoch)
        base = seg_base
        rot_a = euler_to_rot(base[:, ATT])
        tau = seg_tau[:, None]
        pos = (
            base[:, POS]
            + base[:, VEL] * tau
            + 0.5 * GRAVITY * tau**2
            + np.einsum("nij,nj->ni", rot_a, seg_dp)
        )
        vel = base[:, VEL] + GRAVITY * tau + np.einsum("nij,nj->ni", rot_a, seg_dv)
        rot = rot_a @ seg_dR
        att = rot_to_euler(rot)
        # At an epoch the posterior replaces the carried prior.
        pos[ep_seg] = seg_post[ep_seg][:, POS]
        vel[ep_seg] = seg_post[ep_seg][:, VEL]
        att[ep_seg] = seg_post[ep_seg][:, ATT]
        rot[ep_seg] = euler_to_rot(att[ep_seg])
        omega = seg_w
        # base_link: the IMU position less the lever arm; velocity less w x lever.
        lever_base = s.lever_axle
        pos_b = pos + np.einsum("nij,j->ni", rot, lever_base)
        vel_b = vel + np.einsum("nij,nj->ni", rot, np.cross(omega, lever_base))
        rates = euler_rates(att, omega)
        seg_cols = {
            "x": pos_b[:, 0],
            "y": pos_b[:, 1],
            "z": pos_b[:, 2],
            "roll": att[:, 0],
            "pitch": att[:, 1],
            "yaw": att[:, 2],
            "vx": vel_b[:, 0],
            "vy": vel_b[:, 1],
            "vz": vel_b[:, 2],
            "roll_rate": rates[:, 0],
            "pitch_rate": rates[:, 1],
            "yaw_rate": rates[:, 2],
        }
        t_seg = bounds
        if prev_row is not None:
            t_seg = np.concatenate([[prev_row["t"]], t_seg])
            seg_cols = {k: np.concatenate([[prev_row[k]], v]) for k, v in seg_cols.items()}
        seg_cols["yaw"] = np.unwrap(seg_cols["yaw"])
        prev_row = {k: float(v[-1]) for k, v in seg_cols.items()}
        prev_row["t"] = float(t_seg[-1])
        if first_seg_t is None:
            first_seg_t = float(t_seg[0])
        # Output times up to this window's last segment end.
        m_hi = min(int(np.floor((t_seg[-1] - t_start) / step)), n_out_total)
        if m_hi < m_next:
            continue
        t_out, n_left_out = _grid_outside(t_start, step, m_next, m_hi, gaps)
        rows_in_gaps += n_left_out
        m_next = m_hi + 1
        t_out = t_out[t_out >= first_seg_t]
        if t_out.size == 0:
            continue

        columns = {
            k: np.asarray(np.interp(t_out, t_seg, v), dtype=np.float64) for k, v in seg_cols.items()
        }
        columns["yaw"] = wrap_angle(columns["yaw"])
        columns["speed"] = np.hypot(columns["vx"], columns["vy"])
        yield d.t0_ns + np.round(t_out * 1e9).astype(np.int64), columns

    result.gated = dict(ukf.gated)
    result.accepted = dict(ukf.accepted)
    result.down_weighted = dict(ukf.down_weighted)
    result.imu_gaps_bridged = n_bridged
    result.imu_gaps_restarted = n_restart
    result.epochs = int(epochs.size)
    result.imu_samples = n_imu
    result.heading_source = heading_source
    if rows_in_gaps:
        warnings.append(
            f"no pose for {rows_in_gaps * step:.1f} s in {gaps.shape[0]} IMU gap(s) longer than "
            f"{MAX_BRIDGE_S} s: nothing was measured there to estimate it from"
        )
    result.warnings = warnings
    result.reinitialised = n_reinit

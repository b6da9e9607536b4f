"""The causal pose estimator: sensor arrays in, 100 Hz base_link pose out.

Filter steps ("epochs") fall on every valid GPS fix and every compass reading, with filler
epochs so that no step is longer than :data:`MAX_STEP_S` (GPS dropouts coast on IMU, wheels
and the non-holonomic constraint). Between epochs the IMU is pre-integrated sample by sample
(the one Python loop per IMU sample); the same increments carry the posterior mean of the
last epoch forward to every IMU sample, which gives the output between filter steps without
using anything measured later. At each epoch: predict, then GPS, yaw, wheel-speed and
non-holonomic updates, each gated.

IMU gaps: a sample interval longer than 1.5 nominal periods is a gap. Gaps up to
:data:`MAX_BRIDGE_S` are bridged (the next sample's reading is held across the gap); longer
ones restart the filter: the gap is crossed at constant velocity and attitude, and the
covariance is reset to the initial uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit.fusion.rotations import FloatArray, euler_rates, euler_to_rot, rot_to_euler, wrap_angle
from toolkit.fusion.ukf import (
    ATT,
    BG,
    DIM_X,
    GRAVITY,
    NHC_GATE_CHI2,
    NHC_STD_MPS,
    POS,
    VEL,
    ImuIncrement,
    NoiseModel,
    PoseUKF,
    angle_mean,
    angle_residual,
    gps_model,
    nhc_model,
    wheel_model,
    yaw_model,
)

#: Longest filter step, s.
MAX_STEP_S = 0.1
#: Longest IMU gap bridged; a longer one restarts the filter, s.
MAX_BRIDGE_S = 0.5
#: Speed above which the GPS track gives a heading (no compass), m/s.
TRACK_MIN_SPEED_MPS = 3.0


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


def _start(d: SensorData) -> tuple[float, float, str]:
    """Start time, initial yaw and where the heading comes from."""
    t_fix = float(d.gps_t[0])
    if d.head_t.size:
        i = int(np.searchsorted(d.head_t, t_fix))
        if i < d.head_t.size:
            return max(t_fix, float(d.head_t[i])), float(d.head_yaw[i]), "compass"
    # GPS track: the first pair of fixes ~1 s apart moving faster than the threshold.
    j = np.searchsorted(d.gps_t, d.gps_t + 1.0)
    ok = j < d.gps_t.size
    i_idx = np.flatnonzero(ok)
    if i_idx.size:
        jj = j[i_idx]
        disp = d.gps_enu[jj, :2] - d.gps_enu[i_idx, :2]
        dt = d.gps_t[jj] - d.gps_t[i_idx]
        fast = np.hypot(disp[:, 0], disp[:, 1]) / np.maximum(dt, 1e-3) > TRACK_MIN_SPEED_MPS
        if fast.any():
            k = int(np.flatnonzero(fast)[0])
            return float(d.gps_t[jj[k]]), float(np.arctan2(disp[k, 1], disp[k, 0])), "gps_track"
    return t_fix, 0.0, "none"


def _epochs(d: SensorData, t_start: float, t_end: float) -> FloatArray:
    t = np.union1d(d.gps_t, d.head_t)
    t = t[(t > t_start) & (t <= t_end)]
    t = np.concatenate([[t_start], t, [t_end]])
    t = np.unique(t)
    gaps = np.diff(t)
    n_fill = np.maximum(np.ceil(gaps / MAX_STEP_S).astype(int) - 1, 0)
    if n_fill.any():
        fills = [
            t[i] + gaps[i] * np.arange(1, n + 1) / (n + 1) for i, n in enumerate(n_fill) if n > 0
        ]
        t = np.union1d(t, np.concatenate(fills))
    return np.asarray(t[1:], dtype=np.float64)


def estimate(d: SensorData, s: FilterSettings) -> EstimateResult:
    """Run the causal filter over the log (see the module docstring)."""
    t_start, yaw0, heading_source = _start(d)
    warnings: list[str] = []
    if heading_source == "none":
        warnings.append("no compass and the vehicle never moves fast enough for a GPS heading")
    t_end = float(d.imu_t[-1])
    epochs = _epochs(d, t_start, t_end)
    # Segments: the timeline cut at every IMU sample and epoch; each segment holds the IMU
    # sample that ends at or after it (a sample averages the interval before its stamp).
    bounds = np.union1d(d.imu_t[(d.imu_t > t_start) & (d.imu_t <= t_end)], epochs)
    bounds = np.concatenate([[t_start], bounds])
    seg_dt = np.diff(bounds)
    seg_imu = np.searchsorted(d.imu_t, bounds[1:], side="left")
    seg_is_epoch = np.isin(bounds[1:], epochs)
    period = float(np.median(np.diff(d.imu_t))) if d.imu_t.size > 1 else 0.01
    imu_dt = np.diff(d.imu_t, prepend=d.imu_t[0] - period)
    gap_len = imu_dt[seg_imu]
    is_gap = gap_len > 1.5 * period
    restart_seg = is_gap & (gap_len > MAX_BRIDGE_S)
    gap_samples = np.flatnonzero(imu_dt > 1.5 * period)
    gap_samples = gap_samples[d.imu_t[gap_samples] > t_start]
    n_restart = int((imu_dt[gap_samples] > MAX_BRIDGE_S).sum())
    n_bridged = int(gap_samples.size - n_restart)

    # Initial state.
    att0 = _initial_attitude(d, t_start, yaw0)
    i_fix = min(int(np.searchsorted(d.gps_t, t_start)), d.gps_t.size - 1)
    rot0 = euler_to_rot(att0)
    x0 = np.zeros(DIM_X)
    x0[POS] = d.gps_enu[i_fix] - rot0 @ s.lever_gps
    speed0 = float(np.interp(t_start, d.wheel_t, d.wheel_speed)) if d.wheel_t.size else 0.0
    x0[VEL] = rot0 @ np.array([speed0, 0.0, 0.0])
    x0[ATT] = att0
    p0 = np.zeros(DIM_X)
    p0[POS] = s.init_pos_std**2
    p0[VEL] = s.init_vel_std**2
    p0[ATT] = s.init_att_std**2
    if heading_source != "compass":
        p0[8] = 0.3**2
    p0[9:12] = 0.1**2
    p0[12:15] = 0.005**2
    P0 = np.diag(p0)
    ukf = PoseUKF(x0, P0, s.noise, alpha=s.alpha, beta=s.beta, kappa=s.kappa)

    n_seg = seg_dt.size
    n_ep = epochs.size
    post = np.empty((n_ep + 1, DIM_X))  # posterior at the start of epoch k's interval
    post[0] = ukf.x
    seg_tau = np.empty(n_seg)
    seg_dR = np.empty((n_seg, 3, 3))
    seg_dv = np.empty((n_seg, 3))
    seg_dp = np.empty((n_seg, 3))
    seg_w = np.empty((n_seg, 3))
    hx_yaw = yaw_model
    hx_gps = gps_model(s.lever_gps)
    wheel_var = np.array([[s.wheel_var]])
    nhc_cov = np.eye(2) * NHC_STD_MPS**2
    R_heading_idx = {float(t): i for i, t in enumerate(d.head_t.tolist())}
    gps_idx = {float(t): i for i, t in enumerate(d.gps_t.tolist())}
    zero2 = np.zeros(2)

    accel, gyro = d.accel, d.gyro
    k = 0
    inc = ImuIncrement(ukf.x[9:12].copy(), ukf.x[BG].copy())
    restart_pending = False
    for j in range(n_seg):
        i = int(seg_imu[j])
        if restart_seg[j]:
            # Cross a long gap at constant velocity and attitude.
            f_hold = inc.rot_inc.T @ euler_to_rot(post[k, ATT]).T @ (-GRAVITY) + inc.ba0
            inc.add(f_hold, inc.bg0, float(seg_dt[j]))
            restart_pending = True
        else:
            inc.add(accel[i], gyro[i], float(seg_dt[j]))
        seg_tau[j] = inc.T
        seg_dR[j] = inc.rot_inc
        seg_dv[j] = inc.dv
        seg_dp[j] = inc.dp
        seg_w[j] = gyro[min(i, gyro.shape[0] - 1)] - inc.bg0
        if not seg_is_epoch[j]:
            continue
        t = float(bounds[j + 1])
        ukf.predict_imu(inc)
        if restart_pending:
            ukf.P = np.maximum(ukf.P, P0)
            restart_pending = False
        w_now = seg_w[j]
        gi = gps_idx.get(t)
        if gi is not None:
            ukf.update_gated("gps", d.gps_enu[gi], np.diag(d.gps_var[gi]), hx_gps, s.gate_gps)
        hi = R_heading_idx.get(t)
        if hi is not None:
            ukf.update_gated(
                "heading",
                d.head_yaw[hi : hi + 1],
                d.head_var[hi : hi + 1, None],
                hx_yaw,
                s.gate_heading,
                mean_fn=angle_mean,
                residual_fn=angle_residual,
            )
        if d.wheel_t.size and d.wheel_t[0] <= t <= d.wheel_t[-1]:
            speed = float(np.interp(t, d.wheel_t, d.wheel_speed))
            ukf.update_gated(
                "wheels",
                np.array([speed]),
                wheel_var,
                wheel_model(w_now, s.lever_axle),
                s.gate_wheels,
            )
        ukf.update_gated("nhc", zero2, nhc_cov, nhc_model(w_now, s.lever_axle), NHC_GATE_CHI2)
        k += 1
        post[k] = ukf.x
        inc = ImuIncrement(ukf.x[9:12].copy(), ukf.x[BG].copy())

    # The mean carried from each epoch's posterior to every segment end (vectorised).
    ep_seg = np.flatnonzero(seg_is_epoch)
    base = post[np.searchsorted(ep_seg, np.arange(n_seg), side="left")]
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
    pos[ep_seg] = post[1 : ep_seg.size + 1, POS]
    vel[ep_seg] = post[1 : ep_seg.size + 1, VEL]
    att[ep_seg] = post[1 : ep_seg.size + 1, ATT]
    rot[ep_seg] = euler_to_rot(att[ep_seg])
    omega = seg_w
    # base_link: the IMU position less the lever arm; velocity less w x lever.
    lever_base = s.lever_axle
    pos_b = pos + np.einsum("nij,j->ni", rot, lever_base)
    vel_b = vel + np.einsum("nij,nj->ni", rot, np.cross(omega, lever_base))
    rates = euler_rates(att, omega)

    t_seg = bounds[1:]
    step = 1.0 / s.output_rate_hz
    t_out = t_start + step * np.arange(1, int(np.floor((t_seg[-1] - t_start) / step)) + 1)
    t_out = t_out[t_out >= t_seg[0]]

    def interp(col: FloatArray) -> FloatArray:
        return np.asarray(np.interp(t_out, t_seg, col), dtype=np.float64)

    yaw_c = wrap_angle(interp(np.unwrap(att[:, 2])))
    columns = {
        "x": interp(pos_b[:, 0]),
        "y": interp(pos_b[:, 1]),
        "z": interp(pos_b[:, 2]),
        "roll": interp(att[:, 0]),
        "pitch": interp(att[:, 1]),
        "yaw": yaw_c,
        "vx": interp(vel_b[:, 0]),
        "vy": interp(vel_b[:, 1]),
        "vz": interp(vel_b[:, 2]),
        "roll_rate": interp(rates[:, 0]),
        "pitch_rate": interp(rates[:, 1]),
        "yaw_rate": interp(rates[:, 2]),
    }
    columns["speed"] = np.hypot(columns["vx"], columns["vy"])
    t_ns = d.t0_ns + np.round(t_out * 1e9).astype(np.int64)
    return EstimateResult(
        columns=columns,
        t_ns=t_ns,
        gated=dict(ukf.gated),
        accepted=dict(ukf.accepted),
        imu_gaps_bridged=n_bridged,
        imu_gaps_restarted=n_restart,
        epochs=int(n_ep),
        imu_samples=int(np.count_nonzero((d.imu_t > t_start) & (d.imu_t <= t_end))),
        heading_source=heading_source,
        warnings=warnings,
    )

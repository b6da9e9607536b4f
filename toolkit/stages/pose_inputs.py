"""The pose stage's inputs: the ingested sensor tables read into the filter's arrays, and a
re-startable stream over the IMU (the stage: :mod:`toolkit.stages.pose`).

The low-rate GPS, compass and wheel-speed tables are read whole; the IMU is read in batches
of :data:`~toolkit.analysis.pose_accuracy.BATCH_ROWS` (its times for the gaps, its samples
window by window, its orientation thinned to the filter's update rate), so memory is flat in
the log's length. Times are seconds from the IMU's first stamp (``t0_ns``).

The GPS fixes used are those at ``pose.gps_min_status`` or better with finite coordinates,
from the first one the fixes after it agree with
(:func:`~toolkit.geometry.frames.choose_enu_origin`, the ENU frame's origin); without any,
the frame is local, its origin the first pose (wheel speeds dead-reckon).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.spatial.transform import Rotation

from toolkit.analysis.pose_accuracy import column, last_t_ns, table_batches
from toolkit.arrays import FloatArray
from toolkit.config import PoseConfig
from toolkit.errors import StageError
from toolkit.fusion.epochs import MAX_BRIDGE_S, MAX_STEP_S
from toolkit.fusion.estimator_io import ImuWindow, SensorData
from toolkit.geometry.frames import choose_enu_origin
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import geodetic_to_world, grid_minus_true_yaw_rad
from toolkit.geometry.mounts import Mount
from toolkit.geometry.rotations import rot_to_euler
from toolkit.layout import LogFiles
from toolkit.tableio import read_table

IMU_COLUMNS = ["t_ns"] + [f"{q}_{a}" for q in ("accel", "gyro") for a in "xyz"]


@dataclass(frozen=True)
class PoseInputs:
    """What the filter is fed: the low-rate sensors as arrays (``data``, without the IMU's),
    the ENU origin (None without a GPS fix: the frame is then local, its origin the first
    pose), warnings, a factory of IMU windows (each call a new pass over the IMU), the last
    IMU time (s), the nominal IMU period (s, the median interval of the first batch) and the
    IMU gaps the filter restarts across ((K, 2), s)."""

    data: SensorData
    origin: GeodeticOrigin | None
    warnings: list[str]
    imu_windows: Callable[[], Iterator[ImuWindow]]
    t_end: float
    period: float
    imu_gaps: FloatArray


@dataclass(frozen=True)
class _Fixes:
    """The GPS fixes the filter uses (``valid`` (G,)), the ENU origin and warnings."""

    valid: np.ndarray
    origin: GeodeticOrigin | None
    warnings: list[str]


@dataclass(frozen=True)
class _ImuClock:
    """The IMU's first stamp (ns), nominal period (s) and last time (s from the first)."""

    t0_ns: int
    period: float
    t_end: float

    def rel(self, t: np.ndarray) -> FloatArray:
        """Stamps (ns) as seconds from the IMU's first."""
        return (np.asarray(t, dtype=np.int64) - self.t0_ns).astype(np.float64) * 1e-9


def _require_roles(
    log_dir: Path, n_imu: int, n_fixes: int, n_gps: int, n_wheels: int, config: PoseConfig
) -> None:
    """One StageError naming every role pose needs and the log lacks: the IMU drives the
    filter, and a valid GPS fix places the log in the world (without one, wheel speeds let
    it dead-reckon in a local frame)."""
    lacking = []
    if n_imu < 2:
        lacking.append(f"imu ({n_imu} usable rows; accepts sensor_msgs/msg/Imu)")
    if n_fixes == 0 and n_wheels < 2:
        lacking.append(
            f"gps ({n_gps} rows, no fix with status >= {config.gps_min_status}; accepts "
            "sensor_msgs/msg/NavSatFix"
            + ("" if n_wheels else "; nor wheel speeds to dead-reckon")
            + ")"
        )
    if lacking:
        raise StageError(f"pose needs roles the log lacks: {'; '.join(lacking)}", path=log_dir)


def _fix_variances(covs_col: pa.ChunkedArray, idx: np.ndarray, default: FloatArray) -> FloatArray:
    """Per-fix (east, north, up) variances, m^2: each fix's own covariance where it has one
    (the contract's diagonal of 3, or a full 3 x 3 row-major of 9 whose diagonal is taken),
    positive and finite; ``default`` (K, 3) rows elsewhere (unknown covariance is null)."""
    out = default.copy()
    covs = covs_col.combine_chunks().take(pa.array(idx, pa.int64()))
    if len(covs) == 0:
        return out
    lengths = np.asarray(pc.list_value_length(covs).fill_null(0).to_numpy(zero_copy_only=False))
    flat = np.asarray(pc.list_flatten(covs).to_numpy(zero_copy_only=False), dtype=np.float64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    for n, cols in ((3, [0, 1, 2]), (9, [0, 4, 8])):
        rows = np.flatnonzero(lengths == n)
        if rows.size == 0:
            continue
        diag = flat[starts[rows][:, None] + np.asarray(cols)[None, :]]
        ok = np.all(np.isfinite(diag) & (diag > 0.0), axis=1)
        out[rows[ok]] = diag[ok]
    return out


def _imu_attitude(
    imu_path: Path, t0_ns: int, base_from_imu: FloatArray, min_interval_s: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The orientation the IMU reports, as base_link's attitude: (t (K,) s, roll-pitch-yaw
    (K, 3) rad, their variances (K, 3) rad^2, NaN where the IMU gives none).

    The IMU's quaternion is world-from-imu; base_link's attitude is
    ``R_world_base = R_world_imu R_base_imu^T`` (``R_base_imu`` the mount's rotation), read as
    Z-Y-X Euler angles. One sample per ``min_interval_s`` is kept (the filter updates at
    most that often), so memory is that of the GPS, not of the IMU.
    """
    cols = ["t_ns", *(f"orientation_{a}" for a in "xyzw"), "orientation_covariance"]
    ts: list[FloatArray] = []
    rpys: list[FloatArray] = []
    vs: list[FloatArray] = []
    last_slot = -np.inf
    for b in table_batches(imu_path, "imu", cols):
        q = np.stack(
            [
                np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64)
                for i in range(1, 5)
            ],
            axis=1,
        )
        has = np.all(np.isfinite(q), axis=1)
        if not has.any():
            continue
        t = (np.asarray(b.column(0).to_numpy(), np.int64) - t0_ns).astype(np.float64) * 1e-9
        # Thin to one sample per min_interval_s slot (the first with an orientation in each
        # slot), never repeating the slot the previous batch ended in.
        slot = np.floor(t / min_interval_s)
        cand = np.flatnonzero(has & (slot > last_slot))
        _, first = np.unique(slot[cand], return_index=True)
        idx = cand[first]
        if idx.size == 0:
            continue
        last_slot = float(slot[idx[-1]])
        r_wi = Rotation.from_quat(q[idx]).as_matrix()  # world from imu, (K, 3, 3)
        rpys.append(rot_to_euler(r_wi @ base_from_imu.T))
        var = np.full((idx.size, 3), np.nan)
        cov = b.column(5).take(pa.array(idx, pa.int64()))
        lengths = np.asarray(pc.list_value_length(cov).fill_null(0).to_numpy(zero_copy_only=False))
        flat = np.asarray(pc.list_flatten(cov).to_numpy(zero_copy_only=False), np.float64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        for n, sel in ((3, [0, 1, 2]), (9, [0, 4, 8])):
            rows = np.flatnonzero(lengths == n)
            if rows.size:
                var[rows] = flat[starts[rows][:, None] + np.asarray(sel)[None, :]]
        vs.append(var)
        ts.append(t[idx])
    if not ts:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(ts), np.concatenate(rpys), np.concatenate(vs)


def _gps_fixes(
    log_dir: Path, gps: pa.Table, n_imu: int, n_wheels: int, config: PoseConfig
) -> _Fixes:
    """The usable GPS fixes and the ENU origin; refuses a log without the roles pose needs."""
    status = np.asarray(gps.column("status").to_numpy(zero_copy_only=False))
    lat, lon, alt = column(gps, "latitude"), column(gps, "longitude"), column(gps, "altitude")
    valid = (status >= config.gps_min_status) & np.isfinite(lat) & np.isfinite(lon)
    valid &= np.isfinite(alt)
    _require_roles(log_dir, n_imu, int(valid.sum()), gps.num_rows, n_wheels, config)
    chosen = choose_enu_origin(gps, config.gps_min_status) if valid.any() else None
    origin, origin_row = chosen if chosen is not None else (None, 0)
    warnings: list[str] = []
    # Fixes before the origin are the ones their successors disagree with (a receiver's
    # wild first fixes): the filter would start there and gate every good fix after them.
    early = valid & (np.arange(valid.size) < origin_row)
    if early.any():
        warnings.append(
            f"{int(early.sum())} GPS fix(es) before the first one the later fixes agree with "
            "ignored"
        )
        valid &= ~early
    return _Fixes(valid, origin, warnings)


def _imu_clock(imu_path: Path) -> _ImuClock:
    """The IMU's first stamp, nominal period (the median step of the first batch; 0.01 s
    with one row) and last time."""
    first_batch = next(table_batches(imu_path, "imu", ["t_ns"]))
    t_first = np.asarray(first_batch.column(0).to_numpy(), dtype=np.int64)
    t0_ns = int(t_first[0])
    period = float(np.median(np.diff(t_first) * 1e-9)) if t_first.size > 1 else 0.01
    t_end = float(last_t_ns(imu_path) - t0_ns) * 1e-9
    return _ImuClock(t0_ns, period, t_end)


def _imu_gaps(imu_path: Path, clock: _ImuClock) -> FloatArray:
    """The IMU gaps the filter restarts across ((K, 2), s: before and after), from one pass
    over the times alone: steps longer than 1.5 periods and than the filter bridges."""
    gap_parts: list[FloatArray] = []
    last: float | None = None
    for b in table_batches(imu_path, "imu", ["t_ns"]):
        t = clock.rel(b.column(0).to_numpy())
        if last is not None:
            t = np.concatenate([[last], t])
        if t.size:
            dt = np.diff(t)
            k = np.flatnonzero((dt > 1.5 * clock.period) & (dt > MAX_BRIDGE_S))
            gap_parts.append(np.stack([t[k], t[k + 1]], axis=1))
            last = float(t[-1])
    return np.concatenate(gap_parts) if gap_parts else np.zeros((0, 2))


def _imu_window_factory(
    imu_path: Path, clock: _ImuClock, imu_mount: Mount
) -> Callable[[], Iterator[ImuWindow]]:
    """A factory of passes over the IMU, batch by batch: (t (M,) s, specific force (M, 3),
    rate (M, 3)) in base_link axes. The IMU's samples are turned by its mount's rotation
    (specific force and rate are vectors: ``v_base = R v_imu``), so the filter's attitude is
    base_link's whatever way the IMU is mounted."""
    base_from_imu = imu_mount.rotation if imu_mount.is_rotated else None

    def imu_windows() -> Iterator[ImuWindow]:
        for b in table_batches(imu_path, "imu", IMU_COLUMNS):
            t = clock.rel(b.column(0).to_numpy())
            cols = [
                np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64)
                for i in range(1, 7)
            ]
            accel, gyro = np.stack(cols[:3], axis=1), np.stack(cols[3:], axis=1)
            if base_from_imu is not None:  # rows are vectors: (R v)^T = v^T R^T
                accel, gyro = accel @ base_from_imu.T, gyro @ base_from_imu.T
            yield t, accel, gyro

    return imu_windows


def _map_yaw(
    yaw_true_rad: FloatArray,
    head_t: FloatArray,
    gps_t: FloatArray,
    lat_deg: FloatArray,
    lon_deg: FloatArray,
    origin: GeodeticOrigin | None,
) -> FloatArray:
    """A compass's true yaws (K,) turned into the world map's (:mod:`toolkit.geometry.map_frame`:
    by the meridian convergence where the vehicle was, from the GPS fixes ``gps_t`` (N,)
    interpolated to ``head_t`` (K,)). Without a fix there is no map: the yaws as they are."""
    if origin is None or not len(gps_t) or not len(head_t):
        return yaw_true_rad
    lat = np.interp(head_t, gps_t, lat_deg)
    lon = np.interp(head_t, gps_t, np.degrees(np.unwrap(np.radians(lon_deg))))
    return np.asarray(yaw_true_rad + grid_minus_true_yaw_rad(lat, lon, origin), np.float64)


def _low_rate_data(
    files: LogFiles,
    tables: tuple[pa.Table, pa.Table, pa.Table],
    fixes: _Fixes,
    clock: _ImuClock,
    imu_mount: Mount,
    config: PoseConfig,
) -> SensorData:
    """The GPS fixes (ENU, variances), compass, wheel speeds (``tables``: gps, heading,
    wheels) and the IMU's own attitude as the filter's arrays (its IMU arrays empty: the
    IMU is streamed)."""
    gps, head, wheels = tables
    valid, origin = fixes.valid, fixes.origin
    lat, lon, alt = column(gps, "latitude"), column(gps, "longitude"), column(gps, "altitude")

    def rel(table: pa.Table) -> FloatArray:
        return clock.rel(table.column("t_ns").to_numpy())

    gps_t = rel(gps)[valid]
    enu = (
        np.asarray(geodetic_to_world(lat[valid], lon[valid], alt[valid], origin), np.float64)
        if origin is not None
        else np.zeros((0, 3))
    )
    head_t = rel(head)
    head_yaw = _map_yaw(column(head, "yaw"), head_t, gps_t, lat[valid], lon[valid], origin)
    p = config
    default_var = np.array([p.gps_noise_m**2, p.gps_noise_m**2, p.gps_vertical_noise_m**2])
    gvar = np.tile(default_var, (int(valid.sum()), 1))
    gvar = _fix_variances(gps.column("position_covariance"), np.flatnonzero(valid), gvar)
    yaw_std = column(head, "yaw_std") if head.num_rows else np.zeros(0)
    head_var = np.where(np.isfinite(yaw_std) & (yaw_std > 0), yaw_std**2, p.heading_noise_rad**2)
    wheel_speed = column(wheels, "speed") if wheels.num_rows else np.zeros(0)
    wok = np.isfinite(wheel_speed)
    att_t, att_rpy, att_var = _imu_attitude(files.imu, clock.t0_ns, imu_mount.rotation, MAX_STEP_S)
    bad_var = ~(np.isfinite(att_var) & (att_var > 0.0))
    att_var = np.where(bad_var, p.orientation_noise_rad**2, att_var)
    return SensorData(
        t0_ns=clock.t0_ns,
        imu_t=np.zeros(0),
        accel=np.zeros((0, 3)),
        gyro=np.zeros((0, 3)),
        gps_t=gps_t,
        gps_enu=enu,
        gps_var=gvar,
        head_t=head_t,
        head_yaw=head_yaw,
        head_var=head_var,
        wheel_t=rel(wheels)[wok],
        wheel_speed=wheel_speed[wok],
        att_t=att_t,
        att_rpy=att_rpy,
        att_var=att_var,
    )


def sensor_data(log_dir: Path, config: PoseConfig, imu_mount: Mount) -> PoseInputs:
    """The low-rate sensors as arrays and a re-startable stream over the IMU (see
    :class:`PoseInputs`); a StageError naming every role the log lacks."""
    files = LogFiles(log_dir)
    n_imu = read_table(files.imu, "imu", columns=[]).num_rows  # checks the contract
    gps = read_table(files.gps, "gps")
    head = read_table(files.heading, "heading")
    wheels = read_table(files.wheels, "wheels", columns=["t_ns", "speed"])
    fixes = _gps_fixes(log_dir, gps, n_imu, wheels.num_rows, config)
    clock = _imu_clock(files.imu)
    gaps = _imu_gaps(files.imu, clock)
    windows = _imu_window_factory(files.imu, clock, imu_mount)
    data = _low_rate_data(files, (gps, head, wheels), fixes, clock, imu_mount, config)
    return PoseInputs(data, fixes.origin, fixes.warnings, windows, clock.t_end, clock.period, gaps)


__all__ = ["IMU_COLUMNS", "PoseInputs", "sensor_data"]

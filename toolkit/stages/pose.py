"""Pose stage: the ingested sensor tables -> ``pose.parquet`` (100 Hz, causal UKF, sect. 3).

Inputs ``WS/logs/<id>/{imu,gps,heading,wheels}.parquet`` and ``tf_static.json`` (lever arms);
output ``pose.parquet`` (contract columns, base_link in the local ENU frame whose origin is
the first valid GPS fix that the fixes after it agree with,
:func:`~toolkit.frames.choose_enu_origin`; earlier fixes are ignored; stored as JSON under
the ``enu_origin`` metadata key). Manifest record ``pose``: input hashes, config hash, rows,
gating rejections per sensor, IMU gaps bridged / restarted, re-initialisations from the GPS
(``reinitialised``), timings; for simulated logs (``truth_pose.parquet`` and the
``terrain_sim`` record in ``mcap_metadata.json``) an ``accuracy`` header section against
truth: horizontal RMSE (m), roll / pitch / yaw RMSE (deg), position error at the end of each
GPS dropout (m). Idempotent: an up-to-date pose is not recomputed.

Memory is flat in log length: the IMU and truth tables are read in batches of
:data:`BATCH_ROWS`, the filter runs window by window carrying its state
(:func:`~toolkit.fusion.estimator.estimate_stream`), pose rows are streamed to a partial
file renamed into place at the end, and the accuracy keeps only sums of squares. The
low-rate GPS, compass and wheel-speed arrays are held whole.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

from toolkit.config import (
    PipelineConfig,
    PoseConfig,
    TimeConfig,
    TopicsConfig,
    VehicleConfig,
)
from toolkit.errors import StageError
from toolkit.frames import ENU_FRAME_ID, choose_enu_origin
from toolkit.fusion.epochs import MAX_BRIDGE_S, MAX_STEP_S
from toolkit.fusion.estimator import estimate_stream
from toolkit.fusion.estimator_io import (
    EstimateResult,
    FilterSettings,
    ImuWindow,
    OutputChunk,
    SensorData,
)
from toolkit.fusion.process import NoiseModel
from toolkit.fusion.rotations import FloatArray, rot_to_euler, wrap_angle
from toolkit.geodesy import GeodeticOrigin, enu_to_geodetic, geodetic_to_enu
from toolkit.layout import LogFiles, log_file_name
from toolkit.mounts import Mount, sensor_mounts
from toolkit.sim.record import SIM_RECORD
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.tableio import TableWriter, iter_table_batches, read_table, read_table_metadata
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

STAGE = "pose"
#: ``frame_id`` of a pose without GPS: a local frame whose origin is the first pose.
LOCAL_FRAME_ID = "local_first_pose"
INPUT_TABLES = ("imu", "gps", "heading", "wheels")
#: Configuration sections pose reads: the filter, timing, and the vehicle's mounts.
CONFIG_SECTIONS = ("pose", "time", "vehicle")
OUTPUT = log_file_name("pose")
#: Rows per IMU / truth read batch and per output row group.
BATCH_ROWS = 4_096
IMU_COLUMNS = ["t_ns"] + [f"{q}_{a}" for q in ("accel", "gyro") for a in "xyz"]


@dataclass(frozen=True)
class PoseResult:
    """What :func:`run_pose` did for one log."""

    log_id: str
    status: str  # "estimated" or "up_to_date"
    rows: int
    accuracy: dict[str, Any] | None
    seconds: float
    heading_source: str = ""
    accepted: dict[str, int] = field(default_factory=dict)
    gated: dict[str, int] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    #: Readings used beyond their gate with inflated noise (odometry dead reckoning's
    #: wheels; also in ``accepted``), per sensor; empty when none.
    down_weighted: dict[str, int] = field(default_factory=dict)
    #: Without GPS: the mode, the distance (m) and time (s) dead-reckoned; empty with GPS.
    dead_reckoning: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> str:
        """One line for people: rows, what each sensor contributed, the heading's source,
        and (simulated logs) the accuracy against truth."""
        parts = [f"{self.rows} rows"]
        sensors = sorted(self.accepted.keys() | self.gated.keys())
        if sensors:
            parts.append(
                "accepted/gated "
                + ", ".join(
                    f"{k} {self.accepted.get(k, 0)}/{self.gated.get(k, 0)}" for k in sensors
                )
            )
        if self.down_weighted:
            # Outliers that were used, not rejected: still worth a reader's eye.
            parts.append(
                "down-weighted "
                + ", ".join(f"{k} {v}" for k, v in sorted(self.down_weighted.items()))
            )
        if self.heading_source:
            parts.append(f"heading from {self.heading_source}")
        if self.dead_reckoning:
            dr = self.dead_reckoning
            parts.append(
                f"dead-reckoned {float(dr.get('distance_m', 0.0)):.0f} m in "
                f"{float(dr.get('duration_s', 0.0)):.0f} s"
            )
        if self.accuracy:
            a = self.accuracy
            parts.append(
                f"horizontal RMSE {a['horizontal_rmse_m']:.3f} m, roll/pitch/yaw RMSE "
                f"{a['roll_rmse_deg']:.3f}/{a['pitch_rmse_deg']:.3f}/{a['yaw_rmse_deg']:.3f} deg"
            )
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return f"{self.log_id}: pose {self.status.replace('_', ' ')} ({'; '.join(parts)})"


def _col(table: pa.Table, name: str) -> FloatArray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)


def _batches(path: Path, table: str, columns: list[str]) -> Iterator[pa.RecordBatch]:
    """Record batches of a table, in file (time) order, BATCH_ROWS at a time."""
    return iter_table_batches(path, table, columns=columns, batch_rows=BATCH_ROWS)


def _last_t_ns(path: Path) -> int:
    """The last t_ns of a time-sorted table, reading only its last row group."""
    with pq.ParquetFile(path, page_checksum_verification=True) as f:
        rg = f.read_row_group(f.metadata.num_row_groups - 1, columns=["t_ns"])
    return int(rg.column("t_ns")[-1].as_py())


def _require_roles(
    log_dir: Path, n_imu: int, n_fixes: int, n_gps: int, n_wheels: int, config: PoseSettings
) -> None:
    """One StageError naming every role pose needs and the log lacks: the IMU drives the
    filter, and a valid GPS fix places the log in the world (without one, wheel speeds let
    it dead-reckon in a local frame)."""
    lacking = []
    if n_imu < 2:
        lacking.append(f"imu ({n_imu} usable rows; accepts sensor_msgs/msg/Imu)")
    if n_fixes == 0 and n_wheels < 2:
        lacking.append(
            f"gps ({n_gps} rows, no fix with status >= {config.pose.gps_min_status}; accepts "
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
    for b in _batches(imu_path, "imu", cols):
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


def _sensor_data(
    log_dir: Path, config: PoseSettings, imu_mount: Mount
) -> tuple[
    SensorData,
    GeodeticOrigin | None,
    list[str],
    Callable[[], Iterator[ImuWindow]],
    float,
    float,
    FloatArray,
]:
    """The low-rate sensors as arrays and a re-startable stream over the IMU.

    The IMU's samples are turned into base_link axes by its mount's rotation (specific force
    and rate are vectors: ``v_base = R v_imu``), so the filter's attitude is base_link's
    whatever way the IMU is mounted.

    Returns (data without IMU arrays, origin (None without a GPS fix: the frame is then local,
    its origin the first pose), warnings, IMU window factory, last IMU time (s), nominal IMU
    period (s, the median interval of the first batch), the IMU gaps the filter restarts
    across (K, 2), s).
    """
    files = LogFiles(log_dir)
    imu_path = files.imu
    n_imu = read_table(imu_path, "imu", columns=[]).num_rows  # checks the contract
    gps = read_table(files.gps, "gps")
    head = read_table(files.heading, "heading")
    wheels = read_table(files.wheels, "wheels", columns=["t_ns", "speed"])
    status = np.asarray(gps.column("status").to_numpy(zero_copy_only=False))
    lat, lon, alt = _col(gps, "latitude"), _col(gps, "longitude"), _col(gps, "altitude")
    valid = (status >= config.pose.gps_min_status) & np.isfinite(lat) & np.isfinite(lon)
    valid &= np.isfinite(alt)
    _require_roles(log_dir, n_imu, int(valid.sum()), gps.num_rows, wheels.num_rows, config)
    chosen = choose_enu_origin(gps, config.pose.gps_min_status) if valid.any() else None
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
    first_batch = next(_batches(imu_path, "imu", ["t_ns"]))
    t_first = np.asarray(first_batch.column(0).to_numpy(), dtype=np.int64)
    t0_ns = int(t_first[0])
    period = float(np.median(np.diff(t_first) * 1e-9)) if t_first.size > 1 else 0.01
    t_end = float(_last_t_ns(imu_path) - t0_ns) * 1e-9

    def rel_ns(t: np.ndarray) -> FloatArray:
        return (np.asarray(t, dtype=np.int64) - t0_ns).astype(np.float64) * 1e-9

    # The IMU gaps the filter restarts across, from one pass over the times alone.
    gap_parts: list[FloatArray] = []
    last: float | None = None
    for b in _batches(imu_path, "imu", ["t_ns"]):
        t = rel_ns(b.column(0).to_numpy())
        if last is not None:
            t = np.concatenate([[last], t])
        if t.size:
            dt = np.diff(t)
            k = np.flatnonzero((dt > 1.5 * period) & (dt > MAX_BRIDGE_S))
            gap_parts.append(np.stack([t[k], t[k + 1]], axis=1))
            last = float(t[-1])
    imu_gaps = np.concatenate(gap_parts) if gap_parts else np.zeros((0, 2))

    def rel(table: pa.Table) -> FloatArray:
        return rel_ns(table.column("t_ns").to_numpy())

    base_from_imu = imu_mount.rotation if imu_mount.is_rotated else None

    def imu_windows() -> Iterator[ImuWindow]:
        for b in _batches(imu_path, "imu", IMU_COLUMNS):
            t = rel_ns(b.column(0).to_numpy())
            cols = [
                np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64)
                for i in range(1, 7)
            ]
            accel, gyro = np.stack(cols[:3], axis=1), np.stack(cols[3:], axis=1)
            if base_from_imu is not None:  # rows are vectors: (R v)^T = v^T R^T
                accel, gyro = accel @ base_from_imu.T, gyro @ base_from_imu.T
            yield t, accel, gyro

    gps_t = rel(gps)[valid]
    enu = (
        np.asarray(geodetic_to_enu(lat[valid], lon[valid], alt[valid], origin), np.float64)
        if origin is not None
        else np.zeros((0, 3))
    )
    p = config.pose
    default_var = np.array([p.gps_noise_m**2, p.gps_noise_m**2, p.gps_vertical_noise_m**2])
    gvar = np.tile(default_var, (int(valid.sum()), 1))
    gvar = _fix_variances(gps.column("position_covariance"), np.flatnonzero(valid), gvar)
    yaw_std = _col(head, "yaw_std") if head.num_rows else np.zeros(0)
    head_var = np.where(np.isfinite(yaw_std) & (yaw_std > 0), yaw_std**2, p.heading_noise_rad**2)
    wheel_speed = _col(wheels, "speed") if wheels.num_rows else np.zeros(0)
    wok = np.isfinite(wheel_speed)
    att_t, att_rpy, att_var = _imu_attitude(imu_path, t0_ns, imu_mount.rotation, MAX_STEP_S)
    bad_var = ~(np.isfinite(att_var) & (att_var > 0.0))
    att_var = np.where(bad_var, p.orientation_noise_rad**2, att_var)
    data = SensorData(
        t0_ns=t0_ns,
        imu_t=np.zeros(0),
        accel=np.zeros((0, 3)),
        gyro=np.zeros((0, 3)),
        gps_t=gps_t,
        gps_enu=enu,
        gps_var=gvar,
        head_t=rel(head),
        head_yaw=_col(head, "yaw"),
        head_var=head_var,
        wheel_t=rel(wheels)[wok],
        wheel_speed=wheel_speed[wok],
        att_t=att_t,
        att_rpy=att_rpy,
        att_var=att_var,
    )
    return data, origin, warnings, imu_windows, t_end, period, imu_gaps


def _settings(
    config: PoseSettings, lever_gps: FloatArray, lever_axle: FloatArray
) -> FilterSettings:
    p = config.pose
    return FilterSettings(
        noise=NoiseModel(
            p.accel_noise_mps2,
            p.gyro_noise_radps,
            p.accel_bias_walk_mps2,
            p.gyro_bias_walk_radps,
            p.wheel_scale_walk_per_sqrt_s,
        ),
        alpha=p.sigma_alpha,
        beta=p.sigma_beta,
        kappa=p.sigma_kappa,
        gate_gps=p.gate_chi2_gps,
        gate_heading=p.gate_chi2_heading,
        gate_wheels=p.gate_chi2_wheels,
        wheel_var=p.wheel_speed_noise_mps**2,
        init_pos_std=p.initial_position_std_m,
        init_vel_std=p.initial_velocity_std_mps,
        init_att_std=p.initial_attitude_std_rad,
        lever_gps=lever_gps,
        lever_axle=lever_axle,
        output_rate_hz=p.output_rate_hz,
        init_wheel_scale_std=p.initial_wheel_scale_std,
        reinit_after_gated_fixes=p.reinit_after_gated_fixes,
        gate_attitude=p.gate_chi2_attitude,
        track_min_distance_m=p.track_min_distance_m,
        dead_reckoning=p.dead_reckoning,
    )


class TruthAccuracy:
    """Errors of the pose against the simulator's truth, accumulated chunk by chunk.

    The truth table is read in batches alongside the pose rows (both are time-sorted); only
    sums of squares, counts and the error at the end of each GPS dropout are kept.
    """

    def __init__(
        self, truth_path: Path, sim: dict[str, Any], origin: GeodeticOrigin | None
    ) -> None:
        """``origin`` None: the pose is in a local frame (no GPS) whose origin and zero yaw
        are the first pose; the truth is then moved into it (translated to its position and
        turned by its yaw at the first pose time), so the errors are the dead-reckoning's
        drift."""
        # The truth's frame: ingest writes it in the pose's frame (its metadata says so);
        # a table without that metadata is still in the simulator's own frame.
        meta = read_table_metadata(truth_path)
        o = json.loads(meta.get("enu_origin") or sim["origin"])
        self.sim_origin = GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"])
        self.origin = origin
        read_table(truth_path, "truth_pose", columns=[])  # checks the contract
        cols = ["t_ns", "x", "y", "z", "roll", "pitch", "yaw"]
        self._batches = _batches(truth_path, "truth_pose", cols)
        first = next(_batches(truth_path, "truth_pose", ["t_ns"]))
        self.tt0 = int(first.column(0)[0].as_py())
        self.tr_end = float(_last_t_ns(truth_path) - self.tt0)
        self._buf: pa.Table | None = None
        self._exhausted = False
        self.sums = dict.fromkeys(("h", "v", "roll", "pitch", "yaw"), 0.0)
        self.n = 0
        self.t_first: int | None = None
        self.t_last: int | None = None
        self.dropouts = [
            (int(lo), int(hi)) for lo, hi in json.loads(sim.get("gps_dropouts_ns", "[]"))
        ]
        self.drop_err: dict[int, float] = {}
        self.local_ref: tuple[FloatArray, float] | None = None  # truth (xyz, yaw) at start
        self.last_h = 0.0

    def _cover(self, t_hi: int) -> pa.Table:
        """Truth rows from the last one at or before the previous chunk up to >= t_hi."""
        assert self._buf is not None or not self._exhausted
        while not self._exhausted and (
            self._buf is None or int(self._buf.column("t_ns")[-1].as_py()) < t_hi
        ):
            try:
                batch = pa.Table.from_batches([next(self._batches)])
            except StopIteration:
                self._exhausted = True
                break
            self._buf = batch if self._buf is None else pa.concat_tables([self._buf, batch])
        assert self._buf is not None
        return self._buf

    def add(self, t_ns: np.ndarray, cols: dict[str, FloatArray]) -> None:
        if t_ns.size == 0:
            return
        tq = (t_ns - self.tt0).astype(np.float64)
        inside = (tq >= 0.0) & (tq <= self.tr_end)
        if not inside.any():
            return
        truth = self._cover(int(t_ns[inside][-1]))
        tt = np.asarray(truth.column("t_ns").to_numpy(), dtype=np.int64)
        tr = (tt - self.tt0).astype(np.float64)
        tq = tq[inside]
        xyz = np.stack([_col(truth, c) for c in "xyz"], axis=1)
        yaw_shift = 0.0
        if self.origin is None:
            if self.local_ref is None:
                t_ref = tq[0]
                p_ref = np.array([np.interp(t_ref, tr, xyz[:, k]) for k in range(3)])
                yaw_ref = float(np.interp(t_ref, tr, np.unwrap(_col(truth, "yaw"))))
                self.local_ref = (p_ref, yaw_ref)
            p_ref, yaw_shift = self.local_ref
            c, s_ = np.cos(-yaw_shift), np.sin(-yaw_shift)
            d = xyz - p_ref
            xyz = np.stack([c * d[:, 0] - s_ * d[:, 1], s_ * d[:, 0] + c * d[:, 1], d[:, 2]], 1)
        elif self.sim_origin != self.origin:
            lat, lon, alt = enu_to_geodetic(xyz, self.sim_origin)
            xyz = geodetic_to_enu(lat, lon, alt, self.origin)

        def at(v: FloatArray) -> FloatArray:
            return np.asarray(np.interp(tq, tr, v), dtype=np.float64)

        ex = cols["x"][inside] - at(xyz[:, 0])
        ey = cols["y"][inside] - at(xyz[:, 1])
        eh = np.hypot(ex, ey)
        ez = cols["z"][inside] - at(xyz[:, 2])
        self.sums["h"] += float(np.sum(eh**2))
        self.sums["v"] += float(np.sum(ez**2))
        for name in ("roll", "pitch", "yaw"):
            tv = np.unwrap(_col(truth, name)) - (yaw_shift if name == "yaw" else 0.0)
            e = wrap_angle(cols[name][inside] - wrap_angle(at(tv)))
            self.sums[name] += float(np.sum(e**2))
        t_abs = t_ns[inside]
        self.last_h = float(eh[-1])
        self.n += int(t_abs.size)
        if self.t_first is None:
            self.t_first = int(t_abs[0])
        self.t_last = int(t_abs[-1])
        for _lo, hi in self.dropouts:
            k = int(np.searchsorted(t_abs, hi)) - 1
            if k >= 0:
                self.drop_err[hi] = float(eh[k])
        # Keep only the truth rows the next chunk can still need.
        keep_from = max(int(np.searchsorted(tt, int(t_abs[-1]), side="right")) - 1, 0)
        self._buf = truth.slice(keep_from)

    def result(self) -> dict[str, Any] | None:
        if self.n == 0 or self.t_first is None or self.t_last is None:
            return None

        def rms(key: str) -> float:
            return float(np.sqrt(self.sums[key] / self.n))

        dropouts = []
        for lo, hi in self.dropouts:
            if lo < self.t_first or hi > self.t_last or hi not in self.drop_err:
                continue
            dropouts.append(
                {
                    "start_ns": int(lo),
                    "duration_s": round((hi - lo) * 1e-9, 3),
                    "horizontal_error_at_end_m": round(self.drop_err[hi], 4),
                }
            )
        return {
            "rows_compared": self.n,
            "horizontal_rmse_m": round(rms("h"), 4),
            "vertical_rmse_m": round(rms("v"), 4),
            "roll_rmse_deg": round(float(np.degrees(rms("roll"))), 4),
            "pitch_rmse_deg": round(float(np.degrees(rms("pitch"))), 4),
            "yaw_rmse_deg": round(float(np.degrees(rms("yaw"))), 4),
            "gps_dropouts": dropouts,
            "horizontal_error_at_end_m": round(self.last_h, 4),
        }


def truth_accuracy(log_dir: Path, origin: GeodeticOrigin | None) -> TruthAccuracy | None:
    """An accumulator against the simulator's truth, or None for a real log."""
    meta_path, truth_path = LogFiles(log_dir).mcap_metadata, LogFiles(log_dir).truth_pose
    if not (meta_path.is_file() and truth_path.is_file()):
        return None
    try:
        sim = json.loads(meta_path.read_text(encoding="utf-8")).get(SIM_RECORD)
        if not sim or "origin" not in sim:
            return None
        return TruthAccuracy(truth_path, sim, origin)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:  # JSONDecodeError too
        raise StageError(
            f"not the simulator metadata ingest writes ({type(exc).__name__}: {exc}); "
            "run `terrain ingest --overwrite` on its log",
            path=meta_path,
        ) from exc


@dataclass(frozen=True)
class PoseSettings:
    """What pose reads of the configuration: its section, the clocks, the vehicle (mounts,
    lever arms) and the topics (whether the log has a GPS role)."""

    pose: PoseConfig
    time: TimeConfig
    vehicle: VehicleConfig
    topics: TopicsConfig


def run_pose(
    workspace: Workspace, log_id: str, config: PipelineConfig, *, overwrite: bool = False
) -> PoseResult:
    """Estimate the pose of one ingested log (see the module docstring)."""
    result = run_stage(SPEC, workspace, config, log_id=log_id, overwrite=overwrite)
    return cast(PoseResult, result)


def _recall(last: Recalled) -> PoseResult:
    """The outcome of an up-to-date pose, from its record and the manifest's header."""
    detail = last.header.get("pose") or {}
    return PoseResult(
        last.log_id,
        "up_to_date",
        int(last.record.row_counts.get("pose", 0)),
        last.header.get("pose_accuracy"),
        last.seconds,
        heading_source=str(detail.get("heading_source", "")),
        accepted=dict(detail.get("accepted", {})),
        gated=dict(detail.get("gated", {})),
        down_weighted=dict(detail.get("down_weighted", {})),
        dead_reckoning=dict(detail.get("dead_reckoning", {})),
    )


def _compute(call: Call) -> Made:
    """Estimate the pose of the log in ``call.files`` (the module docstring)."""
    config: PoseSettings = call.settings
    log_dir, log_id, start = call.files.dir, call.log_id, call.start
    manifest, cfg_hash, out_path = call.manifest, call.config_hash, call.files.pose
    tf_path = call.files.tf_static
    timings: dict[str, float] = dict.fromkeys(("read", "filter", "write", "accuracy"), 0.0)
    t = time.perf_counter()
    mounts = sensor_mounts(tf_path, config.vehicle, gps=config.topics.gps is not None)
    warnings = list(mounts.warnings)
    data, origin, data_warnings, imu_windows, t_end, period, imu_gaps = _sensor_data(
        log_dir, config, mounts.imu
    )
    warnings += data_warnings
    # Lever arms from the IMU, in base_link axes: to the antenna, and to base_link's origin.
    lever_gps = mounts.gps.translation_m - mounts.imu.translation_m
    lever_axle = -mounts.imu.translation_m
    sha = json.loads(json.dumps(manifest.read().get("source", {}))).get("sha256", "")
    if origin is not None:
        origin_json = json.dumps(
            {
                "latitude_deg": origin.latitude_deg,
                "longitude_deg": origin.longitude_deg,
                "altitude_m": origin.altitude_m,
            }
        )
        frame_meta = {"enu_origin": origin_json, "frame_id": ENU_FRAME_ID}
    else:
        # No GPS: the frame is the first pose's (x forward, z up at that instant, yaw 0).
        t_first_pose = data.t0_ns + int(round(float(data.wheel_t[0]) * 1e9))
        origin_json = json.dumps({"frame": LOCAL_FRAME_ID, "t_ns": t_first_pose})
        frame_meta = {"local_origin": origin_json, "frame_id": LOCAL_FRAME_ID}
    acc = truth_accuracy(log_dir, origin)
    timings["read"] += time.perf_counter() - t
    est = EstimateResult({}, np.zeros(0, np.int64), {}, {}, 0, 0, 0, 0, "")
    rows = 0
    t_first: int | None = None
    t_last: int | None = None
    distance_m = 0.0  # along the written rows, for the dead-reckoning report
    last_xy: tuple[float, float] | None = None
    chunks = estimate_stream(
        data,
        imu_windows,
        _settings(config, lever_gps, lever_axle),
        t_end=t_end,
        period=period,
        result=est,
        imu_gaps=imu_gaps,
    )
    with TableWriter(
        out_path,
        "pose",
        source_sha256=sha,
        config_hash=cfg_hash,
        extra_metadata=frame_meta,
    ) as writer:
        while True:
            t = time.perf_counter()
            chunk: OutputChunk | None = next(chunks, None)
            timings["filter"] += time.perf_counter() - t
            if chunk is None:
                break
            t_ns, cols = chunk
            t = time.perf_counter()
            table = pa.table(
                {
                    "t_ns": pa.array(t_ns, pa.int64()),
                    **{k: pa.array(v, pa.float64()) for k, v in cols.items()},
                }
            )
            writer.write(table)
            timings["write"] += time.perf_counter() - t
            rows += table.num_rows
            if t_ns.size:
                t_first = int(t_ns[0]) if t_first is None else t_first
                t_last = int(t_ns[-1])
                xs, ys = cols["x"], cols["y"]
                if last_xy is not None:
                    xs, ys = np.r_[last_xy[0], xs], np.r_[last_xy[1], ys]
                distance_m += float(np.hypot(np.diff(xs), np.diff(ys)).sum())
                last_xy = (float(xs[-1]), float(ys[-1]))
            if acc is not None:
                t = time.perf_counter()
                acc.add(t_ns, cols)
                timings["accuracy"] += time.perf_counter() - t
    warnings += est.warnings
    duration_s = (
        float(t_last - t_first) * 1e-9 if t_first is not None and t_last is not None else 0.0
    )
    dead_reckoning: dict[str, Any] = {}
    if est.heading_source == "local":
        # Nothing absolute to check the path against, so no number for its error: the
        # filter's covariance in the unobservable directions (position, yaw) grows with its
        # priors (a z gyro bias it never learns), not with the actual drift; on the Husky log
        # it reached a 35 km sigma after 364 m. What is reported is what was dead-reckoned;
        # simulated logs add the error against the truth (accuracy).
        dead_reckoning = {
            "mode": config.pose.dead_reckoning,
            "distance_m": round(distance_m, 3),
            "duration_s": round(duration_s, 3),
        }
        warnings.append(
            f"dead reckoning ({config.pose.dead_reckoning}) over {distance_m:.0f} m in "
            f"{duration_s:.0f} s: nothing absolute bounds its drift"
        )
    accuracy = acc.result() if acc is not None else None
    timings["total"] = time.perf_counter() - start
    filter_detail = {
        ("enu_origin" if origin is not None else "local_origin"): json.loads(origin_json),
        "heading_source": est.heading_source,
        "epochs": est.epochs,
        "imu_samples": est.imu_samples,
        "accepted": dict(sorted(est.accepted.items())),
        "gated": dict(sorted(est.gated.items())),
        # Only odometry dead reckoning down-weights (its wheels); absent otherwise.
        **({"down_weighted": dict(sorted(est.down_weighted.items()))} if est.down_weighted else {}),
        "imu_gaps": {"bridged": est.imu_gaps_bridged, "restarted": est.imu_gaps_restarted},
        "reinitialised": est.reinitialised,
        **({"dead_reckoning": dead_reckoning} if dead_reckoning else {}),
        "x_real_time": round(duration_s / max(timings["filter"], 1e-9), 1),
    }
    outcome = PoseResult(
        log_id,
        "estimated",
        rows,
        accuracy,
        time.perf_counter() - start,
        heading_source=est.heading_source,
        accepted=dict(sorted(est.accepted.items())),
        gated=dict(sorted(est.gated.items())),
        warnings=tuple(warnings),
        down_weighted=dict(sorted(est.down_weighted.items())),
        dead_reckoning=dead_reckoning,
    )
    return Made(
        outcome,
        (OUTPUT,),
        row_counts={"pose": rows},
        rejects={f"gated_{k}": v for k, v in sorted(est.gated.items())},
        timings_s=timings,
        warnings=tuple(warnings),
        header={"pose": filter_detail, "pose_accuracy": accuracy},
    )


SPEC = Stage(
    STAGE,
    "log",
    needs=(
        *(Need(name, "ingest") for name in INPUT_TABLES),
        Need("tf_static", "ingest", optional=True),
        Need("mcap_metadata", "ingest", optional=True),
    ),
    makes=("pose",),
    sections=CONFIG_SECTIONS,
    settings=PoseSettings,
    compute=_compute,
    recall=_recall,
    rows=("pose",),
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "STAGE",
    "PoseResult",
    "PoseSettings",
    "TruthAccuracy",
    "run_pose",
    "stage_config_hash",
]

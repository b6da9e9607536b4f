"""Pose stage: the ingested sensor tables -> ``pose.parquet`` (100 Hz, causal UKF, sect. 3).

Inputs ``WS/logs/<id>/{imu,gps,heading,wheels}.parquet`` and ``tf_static.json`` (lever arms);
output ``pose.parquet`` (contract columns, base_link in the local ENU frame whose origin is
the log's first valid GPS fix, stored as JSON under the ``enu_origin`` metadata key).
Manifest record ``pose``: input hashes, config hash, rows, gating rejections per sensor,
IMU gaps bridged / restarted, timings; for simulated logs (``truth_pose.parquet`` and the
``terrain_sim`` record in ``mcap_metadata.json``) an ``accuracy`` header section against
truth: horizontal RMSE (m), roll / pitch / yaw RMSE (deg), position error at the end of each
GPS dropout (m). Idempotent: an up-to-date pose is not recomputed.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import StageError
from toolkit.fusion.estimator import EstimateResult, FilterSettings, SensorData, estimate
from toolkit.fusion.rotations import FloatArray, wrap_angle
from toolkit.fusion.ukf import NoiseModel
from toolkit.geodesy import GeodeticOrigin, enu_to_geodetic, geodetic_to_enu
from toolkit.tableio import read_table, write_table
from toolkit.workspace import StageRecord, Workspace, check_up_to_date, file_sha256

STAGE = "pose"
INPUT_TABLES = ("imu", "gps", "heading", "wheels")
CONFIG_SECTIONS = ("pose", "time")
OUTPUT = "pose.parquet"


@dataclass(frozen=True)
class PoseResult:
    """What :func:`run_pose` did for one log."""

    log_id: str
    status: str  # "estimated" or "up_to_date"
    rows: int
    accuracy: dict[str, Any] | None
    seconds: float

    def summary(self) -> str:
        """One line for people."""
        acc = ""
        if self.accuracy:
            a = self.accuracy
            acc = (
                f"; horizontal RMSE {a['horizontal_rmse_m']:.3f} m, roll/pitch/yaw RMSE "
                f"{a['roll_rmse_deg']:.3f}/{a['pitch_rmse_deg']:.3f}/{a['yaw_rmse_deg']:.3f} deg"
            )
        return f"{self.log_id}: pose {self.status.replace('_', ' ')} ({self.rows} rows{acc})"


def stage_config_hash(config: PipelineConfig) -> str:
    return config_hash(config, sections=CONFIG_SECTIONS)


def _col(table: pa.Table, name: str) -> FloatArray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)


def _lever_arms(log_dir: Path) -> tuple[FloatArray, FloatArray, list[str]]:
    """(GPS antenna from IMU, base_link origin from IMU), in base_link axes."""
    imu = np.zeros(3)
    gps = np.zeros(3)
    warnings = []
    path = log_dir / "tf_static.json"
    found: dict[str, FloatArray] = {}
    if path.is_file():
        for tf in json.loads(path.read_text())["transforms"]:
            if tf["parent_frame"] == "base_link":
                found[tf["child_frame"]] = np.asarray(tf["translation_m"], dtype=np.float64)
    imu_keys = [k for k in found if "imu" in k]
    gps_keys = [k for k in found if "gps" in k]
    if imu_keys:
        imu = found[imu_keys[0]]
    else:
        warnings.append("no IMU mount in tf_static.json: IMU assumed at base_link")
    if gps_keys:
        gps = found[gps_keys[0]]
    else:
        warnings.append("no GPS antenna mount in tf_static.json: antenna assumed at base_link")
    return gps - imu, -imu, warnings


def _sensor_data(
    log_dir: Path, config: PipelineConfig
) -> tuple[SensorData, GeodeticOrigin, list[str]]:
    tables = {n: read_table(log_dir / f"{n}.parquet", n) for n in INPUT_TABLES}
    imu, gps, head, wheels = (tables[n] for n in INPUT_TABLES)
    if imu.num_rows < 2:
        raise StageError(f"imu table has {imu.num_rows} rows", path=log_dir / "imu.parquet")
    status = np.asarray(gps.column("status").to_numpy(zero_copy_only=False))
    lat, lon, alt = _col(gps, "latitude"), _col(gps, "longitude"), _col(gps, "altitude")
    valid = (status >= config.pose.gps_min_status) & np.isfinite(lat) & np.isfinite(lon)
    valid &= np.isfinite(alt)
    if not valid.any():
        raise StageError(
            f"no valid GPS fix in {gps.num_rows} GPS rows (status >= "
            f"{config.pose.gps_min_status}): cannot place the log in the world",
            path=log_dir / "gps.parquet",
        )
    first = int(np.flatnonzero(valid)[0])
    origin = GeodeticOrigin(float(lat[first]), float(lon[first]), float(alt[first]))
    t0_ns = int(imu.column("t_ns")[0].as_py())

    def rel(table: pa.Table) -> FloatArray:
        t = np.asarray(table.column("t_ns").to_numpy(), dtype=np.int64)
        return (t - t0_ns).astype(np.float64) * 1e-9

    gps_t = rel(gps)[valid]
    enu = geodetic_to_enu(lat[valid], lon[valid], alt[valid], origin)
    cov = gps.column("position_covariance").to_pylist()
    p = config.pose
    default_var = np.array([p.gps_noise_m**2, p.gps_noise_m**2, p.gps_vertical_noise_m**2])
    gvar = np.tile(default_var, (int(valid.sum()), 1))
    idx = np.flatnonzero(valid)
    covs = [cov[i] for i in idx.tolist()]
    if covs and all(c is not None and len(c) == 9 for c in covs):
        diag = np.asarray(covs, dtype=np.float64)[:, [0, 4, 8]]
        ok = np.all(np.isfinite(diag) & (diag > 0), axis=1)
        gvar[ok] = diag[ok]
    yaw_std = _col(head, "yaw_std") if head.num_rows else np.zeros(0)
    head_var = np.where(np.isfinite(yaw_std) & (yaw_std > 0), yaw_std**2, p.heading_noise_rad**2)
    wheel_speed = _col(wheels, "speed") if wheels.num_rows else np.zeros(0)
    wok = np.isfinite(wheel_speed)
    data = SensorData(
        t0_ns=t0_ns,
        imu_t=rel(imu),
        accel=np.stack([_col(imu, f"accel_{a}") for a in "xyz"], axis=1),
        gyro=np.stack([_col(imu, f"gyro_{a}") for a in "xyz"], axis=1),
        gps_t=gps_t,
        gps_enu=enu,
        gps_var=gvar,
        head_t=rel(head),
        head_yaw=_col(head, "yaw"),
        head_var=head_var,
        wheel_t=rel(wheels)[wok],
        wheel_speed=wheel_speed[wok],
    )
    return data, origin, []


def _settings(
    config: PipelineConfig, lever_gps: FloatArray, lever_axle: FloatArray
) -> FilterSettings:
    p = config.pose
    return FilterSettings(
        noise=NoiseModel(
            p.accel_noise_mps2, p.gyro_noise_radps, p.accel_bias_walk_mps2, p.gyro_bias_walk_radps
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
    )


def accuracy_vs_truth(
    log_dir: Path, t_ns: np.ndarray, cols: dict[str, FloatArray], origin: GeodeticOrigin
) -> dict[str, Any] | None:
    """Errors of the pose against the simulator's truth, or None for a real log."""
    meta_path = log_dir / "mcap_metadata.json"
    truth_path = log_dir / "truth_pose.parquet"
    if not (meta_path.is_file() and truth_path.is_file()):
        return None
    sim = json.loads(meta_path.read_text()).get("terrain_sim")
    if not sim or "origin" not in sim:
        return None
    o = json.loads(sim["origin"])
    sim_origin = GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"])
    truth = read_table(truth_path, "truth_pose")
    tt = np.asarray(truth.column("t_ns").to_numpy(), dtype=np.int64)
    xyz_sim = np.stack([_col(truth, c) for c in "xyz"], axis=1)
    lat, lon, alt = enu_to_geodetic(xyz_sim, sim_origin)
    xyz = geodetic_to_enu(lat, lon, alt, origin)
    tq = (t_ns - tt[0]).astype(np.float64)
    tr = (tt - tt[0]).astype(np.float64)
    inside = (tq >= tr[0]) & (tq <= tr[-1])
    tq = tq[inside]

    def at(v: FloatArray) -> FloatArray:
        return np.asarray(np.interp(tq, tr, v), dtype=np.float64)

    ex = cols["x"][inside] - at(xyz[:, 0])
    ey = cols["y"][inside] - at(xyz[:, 1])
    eh = np.hypot(ex, ey)
    errs = {}
    for name in ("roll", "pitch", "yaw"):
        tv = np.unwrap(_col(truth, name))
        errs[name] = wrap_angle(cols[name][inside] - wrap_angle(at(tv)))

    def rms(v: FloatArray) -> float:
        return float(np.sqrt(np.mean(v**2)))

    dropouts = []
    t_abs = t_ns[inside]
    for lo, hi in json.loads(sim.get("gps_dropouts_ns", "[]")):
        if lo < t_abs[0] or hi > t_abs[-1]:
            continue
        k = int(np.searchsorted(t_abs, hi)) - 1
        dropouts.append(
            {
                "start_ns": int(lo),
                "duration_s": round((hi - lo) * 1e-9, 3),
                "horizontal_error_at_end_m": round(float(eh[k]), 4),
            }
        )
    return {
        "rows_compared": int(inside.sum()),
        "horizontal_rmse_m": round(rms(eh), 4),
        "vertical_rmse_m": round(rms(cols["z"][inside] - at(xyz[:, 2])), 4),
        "roll_rmse_deg": round(float(np.degrees(rms(errs["roll"]))), 4),
        "pitch_rmse_deg": round(float(np.degrees(rms(errs["pitch"]))), 4),
        "yaw_rmse_deg": round(float(np.degrees(rms(errs["yaw"]))), 4),
        "gps_dropouts": dropouts,
    }


def run_pose(
    workspace: Workspace, log_id: str, config: PipelineConfig, *, overwrite: bool = False
) -> PoseResult:
    """Estimate the pose of one ingested log (see the module docstring)."""
    start = time.perf_counter()
    log_dir = workspace.log_dir(log_id)
    manifest = workspace.manifest(log_id)
    in_files = [log_dir / f"{n}.parquet" for n in INPUT_TABLES]
    tf_path = log_dir / "tf_static.json"
    for f in in_files:
        if not f.is_file():
            raise StageError("input table missing; run `terrain ingest` first", path=f)
    inputs = {f.stem: file_sha256(f) for f in in_files}
    if tf_path.is_file():
        inputs["tf_static"] = file_sha256(tf_path)
    cfg_hash = stage_config_hash(config)
    out_path = log_dir / OUTPUT
    record = manifest.stage(STAGE)
    if not overwrite and check_up_to_date(
        record, inputs=inputs, config_hash=cfg_hash, outputs=[out_path]
    ):
        assert record is not None
        acc = manifest.read().get("pose_accuracy")
        return PoseResult(
            log_id,
            "up_to_date",
            int(record.row_counts.get("pose", 0)),
            acc,
            time.perf_counter() - start,
        )
    timings: dict[str, float] = {}
    t = time.perf_counter()
    data, origin, warnings = _sensor_data(log_dir, config)
    lever_gps, lever_axle, lw = _lever_arms(log_dir)
    warnings += lw
    timings["read"] = time.perf_counter() - t
    t = time.perf_counter()
    est: EstimateResult = estimate(data, _settings(config, lever_gps, lever_axle))
    timings["filter"] = time.perf_counter() - t
    warnings += est.warnings
    t = time.perf_counter()
    table = pa.table(
        {
            "t_ns": pa.array(est.t_ns, pa.int64()),
            **{k: pa.array(v, pa.float64()) for k, v in est.columns.items()},
        }
    )
    sha = json.loads(json.dumps(manifest.read().get("source", {}))).get("sha256", "")
    origin_json = json.dumps(
        {
            "latitude_deg": origin.latitude_deg,
            "longitude_deg": origin.longitude_deg,
            "altitude_m": origin.altitude_m,
        }
    )
    write_table(
        out_path,
        table,
        "pose",
        source_sha256=sha,
        config_hash=cfg_hash,
        extra_metadata={"enu_origin": origin_json, "frame_id": "enu_first_fix"},
    )
    timings["write"] = time.perf_counter() - t
    t = time.perf_counter()
    accuracy = accuracy_vs_truth(log_dir, est.t_ns, est.columns, origin)
    timings["accuracy"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - start
    duration_s = float(est.t_ns[-1] - est.t_ns[0]) * 1e-9 if est.t_ns.size else 0.0
    filter_detail = {
        "enu_origin": json.loads(origin_json),
        "heading_source": est.heading_source,
        "epochs": est.epochs,
        "imu_samples": est.imu_samples,
        "accepted": dict(sorted(est.accepted.items())),
        "gated": dict(sorted(est.gated.items())),
        "imu_gaps": {"bridged": est.imu_gaps_bridged, "restarted": est.imu_gaps_restarted},
        "x_real_time": round(duration_s / max(timings["filter"], 1e-9), 1),
    }
    manifest.set_header(pose=filter_detail, pose_accuracy=accuracy)
    manifest.record_stage(
        STAGE,
        StageRecord(
            inputs=inputs,
            config_hash=cfg_hash,
            outputs=(OUTPUT,),
            row_counts={"pose": table.num_rows},
            rejects={f"gated_{k}": v for k, v in sorted(est.gated.items())},
            timings_s={k: round(v, 6) for k, v in sorted(timings.items())},
            warnings=tuple(warnings),
        ),
    )
    return PoseResult(log_id, "estimated", table.num_rows, accuracy, time.perf_counter() - start)


__all__ = ["STAGE", "PoseResult", "accuracy_vs_truth", "run_pose", "stage_config_hash"]

"""Pose stage: the ingested sensor tables -> ``pose.parquet`` (100 Hz, causal UKF, sect. 3).

Inputs ``WS/logs/<id>/{imu,gps,heading,wheels}.parquet`` and ``tf_static.json`` (lever arms);
output ``pose.parquet`` (contract columns, base_link in the local ENU frame whose origin is
the first valid GPS fix that the fixes after it agree with,
:func:`~toolkit.geometry.frames.choose_enu_origin`; earlier fixes are ignored; stored as JSON under
the ``enu_origin`` metadata key). Manifest record ``pose``: input hashes, config hash, rows,
gating rejections per sensor, IMU gaps bridged / restarted, re-initialisations from the GPS
(``reinitialised``), timings; for simulated logs (``truth_pose.parquet`` and the
``terrain_sim`` record in ``mcap_metadata.json``) an ``accuracy`` header section against
truth: horizontal RMSE (m), roll / pitch / yaw RMSE (deg), position error at the end of each
GPS dropout (m). Idempotent: an up-to-date pose is not recomputed.

Memory is flat in log length: the IMU and truth tables are read in batches of
:data:`~toolkit.analysis.pose_accuracy.BATCH_ROWS` (:mod:`toolkit.stages.pose_inputs`,
:mod:`toolkit.analysis.pose_accuracy`), the filter runs window by window carrying its state
(:func:`~toolkit.fusion.estimator.estimate_stream`), pose rows are streamed to a partial
file renamed into place at the end, and the accuracy keeps only sums of squares. The
low-rate GPS, compass and wheel-speed arrays are held whole.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.analysis.pose_accuracy import TruthAccuracy, truth_accuracy
from toolkit.arrays import FloatArray
from toolkit.config import (
    PoseConfig,
    TimeConfig,
    TopicsConfig,
    VehicleConfig,
)
from toolkit.fusion.estimator import estimate_stream
from toolkit.fusion.estimator_io import (
    EstimateResult,
    FilterSettings,
    OutputChunk,
    SensorData,
)
from toolkit.fusion.process import NoiseModel
from toolkit.geometry.frames import ENU_FRAME_ID
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.mounts import sensor_mounts
from toolkit.layout import log_file_name
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.pose_inputs import PoseInputs, sensor_data
from toolkit.tableio import TableWriter

_log = logging.getLogger(__name__)

STAGE = "pose"
#: ``frame_id`` of a pose without GPS: a local frame whose origin is the first pose.
LOCAL_FRAME_ID = "local_first_pose"
INPUT_TABLES = ("imu", "gps", "heading", "wheels")
#: The configuration pose's up-to-date key hashes: the filter, timing and the vehicle's
#: mounts. Its settings also hold the topics (whether the log has a GPS role), left out of
#: the key: their changes reach pose through ingest's tables.
CONFIG_SECTIONS = ("pose", "time", "vehicle")
OUTPUT = log_file_name("pose")


@dataclass(frozen=True)
class PoseResult:
    """What the pose stage did for one log."""

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


@dataclass(frozen=True)
class PoseSettings:
    """What pose reads of the configuration: its section, the clocks, the vehicle (mounts,
    lever arms) and the topics (whether the log has a GPS role)."""

    pose: PoseConfig
    time: TimeConfig
    vehicle: VehicleConfig
    topics: TopicsConfig


def _recall(last: Recalled[PoseSettings]) -> PoseResult:
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


@dataclass(frozen=True)
class _Prepared:
    """What pose read before filtering: the inputs, the filter's settings, the output's
    frame (its origin as JSON and the table's metadata) and the truth's accumulator."""

    inputs: PoseInputs
    settings: FilterSettings
    origin_json: str
    frame_meta: dict[str, str]
    accuracy: TruthAccuracy | None
    warnings: list[str]


def _frame(origin: GeodeticOrigin | None, data: SensorData) -> tuple[str, dict[str, str]]:
    """The output frame's origin (JSON) and the pose table's frame metadata: local ENU at
    the GPS origin, or without GPS the first pose's frame (x forward, z up at that instant,
    yaw 0)."""
    if origin is not None:
        origin_json = json.dumps(
            {
                "latitude_deg": origin.latitude_deg,
                "longitude_deg": origin.longitude_deg,
                "altitude_m": origin.altitude_m,
            }
        )
        return origin_json, {"enu_origin": origin_json, "frame_id": ENU_FRAME_ID}
    t_first_pose = data.t0_ns + int(round(float(data.wheel_t[0]) * 1e9))
    origin_json = json.dumps({"frame": LOCAL_FRAME_ID, "t_ns": t_first_pose})
    return origin_json, {"local_origin": origin_json, "frame_id": LOCAL_FRAME_ID}


def _prepare(call: Call[PoseSettings]) -> _Prepared:
    """The mounts, the sensor data (:mod:`toolkit.stages.pose_inputs`), the lever arms from
    the IMU in base_link axes (to the antenna, and to base_link's origin), the frame and,
    on a simulated log, the truth's accumulator."""
    config = call.settings
    mounts = sensor_mounts(call.files.tf_static, config.vehicle, gps=config.topics.gps is not None)
    warnings = list(mounts.warnings)
    inputs = sensor_data(call.files.dir, config.pose, mounts.imu)
    warnings += inputs.warnings
    lever_gps = mounts.gps.translation_m - mounts.imu.translation_m
    lever_axle = -mounts.imu.translation_m
    origin_json, frame_meta = _frame(inputs.origin, inputs.data)
    acc = truth_accuracy(call.files.dir, inputs.origin)
    settings = _settings(config, lever_gps, lever_axle)
    return _Prepared(inputs, settings, origin_json, frame_meta, acc, warnings)


class _PathTally:
    """The written rows: their count, first and last times (ns) and the distance along
    them (m, for the dead-reckoning report)."""

    def __init__(self) -> None:
        self.rows = 0
        self.t_first: int | None = None
        self.t_last: int | None = None
        self.distance_m = 0.0
        self._last_xy: tuple[float, float] | None = None

    def add(self, t_ns: np.ndarray, cols: dict[str, FloatArray]) -> None:
        """Count a chunk of rows."""
        self.rows += int(t_ns.size)
        if not t_ns.size:
            return
        self.t_first = int(t_ns[0]) if self.t_first is None else self.t_first
        self.t_last = int(t_ns[-1])
        xs, ys = cols["x"], cols["y"]
        if self._last_xy is not None:
            xs, ys = np.r_[self._last_xy[0], xs], np.r_[self._last_xy[1], ys]
        self.distance_m += float(np.hypot(np.diff(xs), np.diff(ys)).sum())
        self._last_xy = (float(xs[-1]), float(ys[-1]))

    @property
    def duration_s(self) -> float:
        """From the first written row to the last, s (0 without rows)."""
        if self.t_first is None or self.t_last is None:
            return 0.0
        return float(self.t_last - self.t_first) * 1e-9


def _estimate(
    call: Call[PoseSettings], prep: _Prepared, est: EstimateResult, timings: dict[str, float]
) -> _PathTally:
    """Run the filter window by window (:func:`~toolkit.fusion.estimator.estimate_stream`),
    streaming its rows into ``pose.parquet`` and into the truth's accumulator."""
    inputs, acc, tally = prep.inputs, prep.accuracy, _PathTally()
    chunks = estimate_stream(
        inputs.data,
        inputs.imu_windows,
        prep.settings,
        t_end=inputs.t_end,
        period=inputs.period,
        result=est,
        imu_gaps=inputs.imu_gaps,
    )
    sha = json.loads(json.dumps(call.manifest.read().get("source", {}))).get("sha256", "")
    with TableWriter(
        call.files.pose,
        "pose",
        source_sha256=sha,
        config_hash=call.config_hash,
        extra_metadata=prep.frame_meta,
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
            tally.add(t_ns, cols)
            if acc is not None:
                t = time.perf_counter()
                acc.add(t_ns, cols)
                timings["accuracy"] += time.perf_counter() - t
    return tally


def _dead_reckoning(
    config: PoseSettings, est: EstimateResult, tally: _PathTally, warnings: list[str]
) -> dict[str, Any]:
    """Without GPS (a local heading), what was dead-reckoned, with a warning; empty with GPS.

    Nothing absolute checks the path, so no number for its error: the filter's covariance in
    the unobservable directions (position, yaw) grows with its priors (a z gyro bias it
    never learns), not with the actual drift; on the Husky log it reached a 35 km sigma
    after 364 m. Simulated logs add the error against the truth (accuracy)."""
    if est.heading_source != "local":
        return {}
    distance_m, duration_s = tally.distance_m, tally.duration_s
    digits_m, digits_s = (2 if v < 10 else 0 for v in (distance_m, duration_s))  # no "0 s"
    warnings.append(
        f"dead reckoning ({config.pose.dead_reckoning}) over {distance_m:.{digits_m}f} m in "
        f"{duration_s:.{digits_s}f} s: nothing absolute bounds its drift"
    )
    return {
        "mode": config.pose.dead_reckoning,
        "distance_m": round(distance_m, 3),
        "duration_s": round(duration_s, 3),
    }


def _made(
    call: Call[PoseSettings],
    prep: _Prepared,
    est: EstimateResult,
    tally: _PathTally,
    timings: dict[str, float],
    warnings: list[str],
) -> Made[PoseResult]:
    """The outcome and what the runner records (the header's ``pose`` and
    ``pose_accuracy``)."""
    dead_reckoning = _dead_reckoning(call.settings, est, tally, warnings)
    accuracy = prep.accuracy.result() if prep.accuracy is not None else None
    timings["total"] = time.perf_counter() - call.start
    origin_key = "enu_origin" if prep.inputs.origin is not None else "local_origin"
    filter_detail = {
        origin_key: json.loads(prep.origin_json),
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
        "x_real_time": round(tally.duration_s / max(timings["filter"], 1e-9), 1),
    }
    outcome = PoseResult(
        call.log_id,
        "estimated",
        tally.rows,
        accuracy,
        time.perf_counter() - call.start,
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
        row_counts={"pose": tally.rows},
        rejects={f"gated_{k}": v for k, v in sorted(est.gated.items())},
        timings_s=timings,
        warnings=tuple(warnings),
        header={"pose": filter_detail, "pose_accuracy": accuracy},
    )


def _compute(call: Call[PoseSettings]) -> Made[PoseResult]:
    """Estimate the pose of the log in ``call.files`` (the module docstring)."""
    timings: dict[str, float] = dict.fromkeys(("read", "filter", "write", "accuracy"), 0.0)
    t = time.perf_counter()
    prep = _prepare(call)
    timings["read"] += time.perf_counter() - t
    est = EstimateResult({}, np.zeros(0, np.int64), {}, {}, 0, 0, 0, 0, "")
    tally = _estimate(call, prep, est, timings)
    warnings = prep.warnings + list(est.warnings)
    return _made(call, prep, est, tally, timings, warnings)


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


__all__ = [
    "SPEC",
    "STAGE",
    "PoseResult",
    "PoseSettings",
    "TruthAccuracy",
]

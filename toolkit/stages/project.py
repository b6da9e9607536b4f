"""Project stage: laser scans + pose -> the 3-D point cloud ``points.parquet`` (paper sect. 3).

Every return of every scan becomes a world point of the paper's eq. (1), ``L_i = [x, y, z,
tau, gamma, psi]``, placed with the pose *at the beam's own time* and the laser's mount
(``base_link_from_laser``, from ``tf_static.json`` by the scan's ``frame_id``,
:func:`~toolkit.geometry.mounts.frame_mounts`): the arithmetic, its interpolation of the pose on the
rotation group and the reasons a return is dropped are :mod:`toolkit.model.projection`'s.
The pose is the causal filter output, what the vehicle knew while driving, as the paper
projects with. Each point keeps its laser, beam, range, scan time (``scan_t_ns``) and the
time since that laser's previous scan (``scan_dt_s``, NaN for a laser's first scan), and the
roll and pitch rates at its time (the paper's gamma and psi; its tau is ``t_ns``).

Dropped returns are counted by reason (manifest ``rejects``; a warning on the terminal when
any are): ``bad_scan``, ``no_return``, ``out_of_range``, ``no_pose`` and ``no_mount``
(:data:`~toolkit.model.projection.REJECT_REASONS`).

Memory is bounded: scans are read :data:`SCAN_BATCH` at a time and the pose is streamed
alongside them (:class:`~toolkit.stages.project_scans.PoseStream`), so neither the scans nor
the cloud of a long log is ever whole in memory. Points are written in scan order (scans by
time, beams in order). Beside them the stage writes the paper's Fig. 4 from the log and, on
simulated logs, the points' z error against the true terrain
(:mod:`toolkit.stages.project_figures`).
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.analysis.fig4 import ScanAgreementResult
from toolkit.config import (
    ModelConfig,
    PipelineConfig,
    ProjectConfig,
    TopicsConfig,
    VehicleConfig,
)
from toolkit.errors import StageError
from toolkit.geometry.mounts import Mount, frame_mounts
from toolkit.layout import LogFiles, log_file_name
from toolkit.model.projection import Counts, PoseWindow, PreparedBatch
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.project_figures import FIGURE_BYTES, Figures, ZSample
from toolkit.stages.project_lidar import LidarSource, lidar_frames
from toolkit.stages.project_scans import (
    LASER_COLUMNS,
    PoseStream,
    ScanBatch,
    laser_frames,
    prepare_batch,
    project_batch,
    project_prepared,
)
from toolkit.tableio import TableWriter, iter_table_batches, read_table, read_table_metadata
from toolkit.tyre_paths import PATH_SETTINGS, NearPath, PathsDrawnFrom, cut_metadata

_log = logging.getLogger(__name__)

STAGE = "project"
OUTPUT = log_file_name("points")
#: Configuration sections projection reads: the vehicle (its base frame, for the mounts; its
#: track, for the tyres' paths) and which points to keep; with ``keep = "near_path"`` also
#: the tables' radius around a tyre and what the paths are drawn from
#: (:func:`hashed_sections`).
CONFIG_SECTIONS = ("vehicle", "project")
#: Scans per read batch (5 lasers x 181 beams: ~360 k points, ~40 MB of arrays in flight).
SCAN_BATCH = 2_000
#: The cloud's columns whose row groups carry min/max statistics: those a reader selects
#: points by (time, laser, place). The others' statistics cost 8 % of the writing (measured:
#: 10.2 against 9.4 M rows/s), and writing bounds the stage on long logs.
POINT_STATISTICS = ("t_ns", "scan_t_ns", "laser", "x", "y")
#: Threads projecting batches at once: the machine's two cores (reading and writing, in
#: pyarrow, run beside them outside the GIL too).
WORKERS = 2


@dataclass(frozen=True)
class ProjectResult:
    """What the project stage did for one log."""

    log_id: str
    status: str  # "projected" or "up_to_date"
    points: int
    scans: int
    rejects: dict[str, int]
    seconds: float
    warnings: tuple[str, ...] = ()
    #: Points per second of projection proper (reading and writing excluded).
    points_per_s: float = 0.0
    #: The paper's Fig. 4 from this log, in words (its fit; files beside the points).
    fig4: str = ""
    #: Points projected but left out, far from the tyres' paths (``keep = "near_path"``).
    far_from_path: int = 0

    def summary(self) -> str:
        """One line for people: points, scans, what was dropped and why."""
        parts = [f"{self.points} points from {self.scans} scans"]
        if self.far_from_path:
            parts.append(f"{self.far_from_path} far from the tyres' paths left out")
        dropped = {k: v for k, v in self.rejects.items() if v}
        if dropped:
            parts.append("dropped " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
        if self.fig4:
            parts.append(self.fig4)
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return f"{self.log_id}: points {self.status.replace('_', ' ')} ({'; '.join(parts)})"


def hashed_sections(config: PipelineConfig) -> tuple[str, ...]:
    """What projection reads of ``config``: cutting near the tyres' paths, also the tables'
    radius and the settings the paths are drawn from
    (:data:`~toolkit.tyre_paths.PATH_SETTINGS`; their inputs,
    :data:`~toolkit.tyre_paths.PATH_INPUTS`, are among the stage's needs), so a change that
    moves the paths redoes the cut."""
    if config.project.keep == "near_path":
        return (*CONFIG_SECTIONS, "model.wheel_window_radius_m", *PATH_SETTINGS)
    # Keeping every point, the margin is not read: changing it leaves the cloud as it is.
    return ("vehicle", "project.keep")


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProjectSettings:
    """What projection reads of the configuration: its section, the vehicle (the lasers'
    mounts), the topics (whether the log has lasers) and the model (the tyres' radius, for
    ``keep = "near_path"``)."""

    project: ProjectConfig
    vehicle: VehicleConfig
    topics: TopicsConfig
    model: ModelConfig


def _require_scanner(files: LogFiles, config: ProjectSettings) -> None:
    """StageError when the log has nothing to project, or both kinds of scanner."""
    lasers = config.topics.lasers != () and files.laser.is_file()
    lidars = config.topics.lidars != () and files.lidar.is_file()
    if lasers and lidars and _has_rows(files.laser):
        raise StageError(
            "this log has lasers and 3-D lidars, and project reads one kind at a time: set "
            "[topics] lasers = [] or lidars = [] (a configuration for each, one workspace each)",
            path=files.dir,
        )
    if not (lasers or lidars):
        raise StageError(
            "projection needs a scanner, and this log has none: [topics] lasers accepts "
            "sensor_msgs/msg/LaserScan topics, lidars sensor_msgs/msg/PointCloud2",
            path=files.laser,
        )


def _has_rows(path: Path) -> bool:
    return bool(pq.ParquetFile(path).metadata.num_rows)


def _reads_lidar(files: LogFiles, config: ProjectSettings) -> bool:
    """Whether the log's points come from its 3-D lidars (else from its lasers)."""
    return config.topics.lidars != () and files.lidar.is_file()


def _recall(last: Recalled[ProjectSettings]) -> ProjectResult:
    """The outcome of an up-to-date projection, from its record."""
    record = last.record
    return ProjectResult(
        last.log_id,
        "up_to_date",
        int(record.row_counts.get("points", 0)),
        int(record.row_counts.get("scans", 0)),
        {k: int(v) for k, v in record.rejects.items()},
        last.seconds,
        far_from_path=int(record.row_counts.get("far_from_path", 0)),
    )


def _compute(call: Call[ProjectSettings]) -> Made[ProjectResult]:
    """Project the scans of the log in ``call.files`` (the module docstring): open the
    inputs, project and write the batches, then write the figures."""
    config = call.settings
    lidar = _reads_lidar(call.files, config)
    _require_disk_for_cloud(call.files.lidar if lidar else call.files.laser, config)
    timings = dict.fromkeys(("read", "project", "write", "figures"), 0.0)
    inputs = _open_inputs(call, config, lidar)
    figures = Figures(call.files.dir, inputs.warnings)
    source: _Source = (
        LidarSource(call.files.lidar, inputs.mounts, inputs.poses)
        if lidar
        else _LaserSource(call.files.laser, inputs.mounts, inputs.poses)
    )
    with TableWriter(
        call.files.points,
        "points",
        source_sha256=inputs.source_sha256,
        config_hash=call.config_hash,
        extra_metadata=inputs.frame_meta,
        bulk=True,
        statistics=POINT_STATISTICS,
    ) as writer:
        loop = _BatchLoop(writer, figures, inputs.near_path, timings)
        loop.run(source)
    t = time.perf_counter()
    fig4, figure_files = figures.write(call.files.dir, call.log_id)
    timings["figures"] += time.perf_counter() - t
    return _made(call, loop, fig4, figure_files, inputs.warnings)


@dataclass(frozen=True)
class _Inputs:
    """What projecting a log reads before its first scan: the lasers' mounts, the pose's
    frame (carried to the points' metadata), the source's hash, the pose stream and which
    points to keep; ``warnings`` collects the stage's warnings from here on."""

    mounts: dict[str, Mount]
    warnings: list[str]
    frame_meta: dict[str, str]
    source_sha256: str
    poses: PoseStream
    near_path: NearPath | None


def _open_inputs(call: Call[ProjectSettings], config: ProjectSettings, lidar: bool) -> _Inputs:
    """The mounts of the scans' (or the lidar returns') frames, the pose's frame metadata and
    stream, and (with ``keep = "near_path"``) the tyres' paths, for the log in ``call.files``."""
    files = call.files
    frames = lidar_frames(files.lidar) if lidar else laser_frames(files.laser)
    mounts, mount_warnings = frame_mounts(files.tf_static, config.vehicle.base_frame, frames)
    pose_meta = read_table_metadata(files.pose)
    frame_meta: dict[str, str] = {
        k: pose_meta[k] for k in ("frame_id", "enu_origin", "local_origin") if k in pose_meta
    }
    sha = json.loads(json.dumps(call.manifest.read().get("source", {}))).get("sha256", "")
    poses = PoseStream(files.pose)
    near_path = _near_path(files.pose, config)
    if near_path is not None:  # stamped with what the paths are drawn from, for its readers
        drawn_from = PathsDrawnFrom.of(config, call.inputs)
        frame_meta.update(cut_metadata(near_path.distance_m, drawn_from))
    return _Inputs(mounts, list(mount_warnings), frame_meta, sha, poses, near_path)


class _Source(Protocol):
    """What the batch loop projects: record batches in time order, their sequential
    preparation (here) and their projection (a pure function, on a worker thread)."""

    batches: Iterator[pa.RecordBatch]

    def prepare(self, batch: pa.RecordBatch) -> Any: ...

    def project(self, prepared: Any) -> tuple[pa.Table, Counts]: ...


class _LaserSource:
    """The laser table's scans (:mod:`toolkit.stages.project_scans`)."""

    def __init__(self, laser_path: Path, mounts: dict[str, Mount], poses: PoseStream) -> None:
        self.batches: Iterator[pa.RecordBatch] = iter_table_batches(
            laser_path, "laser", columns=LASER_COLUMNS, batch_rows=SCAN_BATCH
        )
        self._mounts = mounts
        self._poses = poses
        self._previous_scan_ns: dict[str, int] = {}

    def prepare(self, batch: pa.RecordBatch) -> PreparedBatch:
        scans = ScanBatch.from_record_batch(batch)
        return prepare_batch(scans, self._mounts, self._poses, self._previous_scan_ns)

    @staticmethod
    def project(prepared: PreparedBatch) -> tuple[pa.Table, Counts]:
        return project_prepared(prepared)


class _Projected(NamedTuple):
    """A batch projected on a worker thread: every point projected (``table``), those the
    cloud keeps (``kept``), its counts, its z-error sample and the seconds it took."""

    table: pa.Table
    kept: pa.Table
    counts: Counts
    sample: ZSample | None
    seconds: float


@dataclass
class _BatchLoop:
    """The scans' batches prepared in order here (the pose stream and each laser's previous
    scan are sequential), projected by a pool of :data:`WORKERS` threads (numpy and the
    truth lookup release the GIL in their loops), then written here and handed to the
    figures, in order: the output is the same as projecting one batch after another, and
    reading, projecting, writing (pyarrow's encoding and compression, also outside the GIL)
    and Fig. 4 overlap on the machine's cores. At most WORKERS + 1 batches are in flight and
    :data:`~toolkit.stages.project_figures.FIGURE_QUEUE` with Fig. 4, so memory stays
    bounded. (A separate writer thread was tried: no faster on two cores, measured; Fig. 4
    on its own thread took the 10-minute log's loop from 10.9-11.5 s to 10.5-10.9 s.)"""

    writer: TableWriter
    figures: Figures
    near_path: NearPath | None
    #: Seconds per step, added to (``read``, ``project``, ``write``, ``figures``; ``loop``).
    timings: dict[str, float]
    counts: Counts = field(default_factory=Counts)
    #: Points projected but left out, far from the tyres' paths.
    far_from_path: int = 0

    def run(self, source: _Source) -> None:
        """Project and write every batch of ``source``."""
        loop_start = time.perf_counter()
        pending: deque[Future[_Projected]] = deque()
        with (
            ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="project") as pool,
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="fig4") as figure_pool,
        ):
            try:
                while True:
                    t = time.perf_counter()
                    batch = next(source.batches, None)
                    if batch is None:
                        break
                    prepared = source.prepare(batch)
                    self.timings["read"] += time.perf_counter() - t
                    pending.append(pool.submit(self.work, source.project, prepared))
                    if len(pending) > WORKERS:
                        self.finish(pending.popleft(), figure_pool)
                while pending:
                    self.finish(pending.popleft(), figure_pool)
                self.figures.drain()
            finally:
                for future in pending:  # an error: let nothing run on behind it
                    future.cancel()
                self.figures.cancel()
        self.timings["loop"] = time.perf_counter() - loop_start

    def work(self, project: Callable[[Any], tuple[pa.Table, Counts]], prepared: Any) -> _Projected:
        """Project a batch (on a worker thread): its points, those kept, its z-error sample."""
        t0 = time.perf_counter()
        table, batch_counts = project(prepared)
        sample = self.figures.sample(table)
        kept = table
        if self.near_path is not None:
            x, y = table.column("x").to_numpy(), table.column("y").to_numpy()
            kept = table.filter(pa.array(self.near_path.mask(x, y)))
        return _Projected(table, kept, batch_counts, sample, time.perf_counter() - t0)

    def finish(self, future: Future[_Projected], figure_pool: ThreadPoolExecutor) -> None:
        """Write a projected batch's kept points and feed all of them to the figures (so
        ``timings["figures"]`` is this thread's waiting for Fig. 4, not Fig. 4's own work)."""
        projected = future.result()
        self.timings["project"] += projected.seconds
        self.counts.add(projected.counts)
        self.far_from_path += projected.table.num_rows - projected.kept.num_rows
        t = time.perf_counter()
        self.writer.write(projected.kept)
        self.timings["write"] += time.perf_counter() - t
        t = time.perf_counter()
        self.figures.feed(projected.table, projected.sample, figure_pool)
        self.timings["figures"] += time.perf_counter() - t


def _made(
    call: Call[ProjectSettings],
    loop: _BatchLoop,
    fig4: ScanAgreementResult,
    figure_files: list[str],
    warnings: list[str],
) -> Made[ProjectResult]:
    """The stage's outcome and record from a finished projection."""
    counts, far_from_path, timings = loop.counts, loop.far_from_path, loop.timings
    dropped = {k: v for k, v in counts.rejects.items() if v}
    returns = counts.points + sum(counts.rejects.values())
    if dropped:
        warnings.append(
            f"{sum(dropped.values())} of {returns} returns dropped ("
            + ", ".join(f"{k} {v}" for k, v in dropped.items())
            + ")"
        )
    if far_from_path and far_from_path == counts.points:
        warnings.append(
            f"none of the {counts.points} projected returns lies near the tyres' paths "
            '([project] keep = "near_path"): the cloud is empty; keep = "all" keeps them'
        )
    timings["total"] = time.perf_counter() - call.start
    outcome = ProjectResult(
        call.log_id,
        "projected",
        counts.points - far_from_path,
        counts.scans,
        dict(counts.rejects),
        time.perf_counter() - call.start,
        warnings=tuple(warnings),
        points_per_s=counts.points / max(timings["loop"], 1e-9),
        fig4=f"Fig. 4 {fig4.fit.describe()}",
        far_from_path=far_from_path,
    )
    return Made(
        outcome,
        (OUTPUT, *figure_files),
        row_counts={
            "points": counts.points - far_from_path,
            "scans": counts.scans,
            "far_from_path": far_from_path,
        },
        rejects=dict(counts.rejects),
        timings_s=timings,
        warnings=tuple(warnings),
        header=_fig4_header(fig4, figure_files),
    )


def _fig4_header(fig4: ScanAgreementResult, figure_files: list[str]) -> dict[str, object]:
    """The manifest's header field of the stage: Fig. 4's fit and the figures' files."""
    fit = fig4.fit
    return {
        "project": {
            "fig4": {  # NaN (too few pairs for a line) is written as null
                "slope_m_per_s": _finite_or_none(fit.slope_m_per_s),
                "intercept_m": _finite_or_none(fit.intercept_m),
                "r2": _finite_or_none(fit.r2),
                "pairs": fig4.pairs,
                "flat_points": fig4.flat_points,
                "files": figure_files,
            }
        }
    }


#: Bytes a point of the cloud takes on disk, measured on a 20-mile race (benchmarks/README.md,
#: "Disk"): every point kept (8.8), and per point projected when only those near the tyres'
#: paths are kept (13.6 bytes for each of the 11 % kept); rounded up.
CLOUD_BYTES_PER_RETURN = {"all": 9.0, "near_path": 1.6}


def _require_disk_for_cloud(laser_path: Path, config: ProjectSettings) -> None:
    """StageError, before anything is written, when the disk cannot hold what the stage
    writes: the cloud, its size estimated from the scans' returns (the ``ranges`` values
    counted in the Parquet footer, not read; a lidar table's rows) at
    :data:`CLOUD_BYTES_PER_RETURN`, and the figures beside it
    (:data:`~toolkit.stages.project_figures.FIGURE_BYTES`), against the free space beside
    it. An old cloud's room is not free: the new one is written aside in a new generation of
    the log while the old one stays in the current generation until the stage commits."""
    meta = pq.ParquetFile(laser_path).metadata
    leaf = next(
        (
            j
            for j in range(meta.num_columns)
            if meta.schema.column(j).path.split(".")[0] == "ranges"
        ),
        None,
    )
    if leaf is None:  # a 3-D lidar's table: a row a return
        returns = meta.num_rows
    else:
        returns = sum(meta.row_group(i).column(leaf).num_values for i in range(meta.num_row_groups))
    need = returns * CLOUD_BYTES_PER_RETURN[config.project.keep] + FIGURE_BYTES
    free = shutil.disk_usage(laser_path.parent).free
    _log.info(
        "the point cloud of %d returns and its figures will take about %.2f GB", returns, need / 1e9
    )
    if need > free:
        hint = (
            '; [project] keep = "near_path" keeps only the points the tables use, about a sixth'
            if config.project.keep == "all"
            else ""
        )
        raise StageError(
            f"the point cloud of {returns} laser returns, with its figures, needs about "
            f"{need / 1e9:.2f} GB and {free / 1e9:.2f} GB are free on this disk: make room{hint}",
            path=laser_path.parent,
        )


def _near_path(pose_path: Path, config: ProjectSettings) -> NearPath | None:
    """What tells the points near the rear tyres' paths (``[project] keep = "near_path"``):
    within the tables' radius plus the margin; None when every point is kept."""
    if config.project.keep != "near_path":
        return None
    pose = read_table(pose_path, "pose", columns=["t_ns", "x", "y", "yaw"])
    return NearPath(
        pose.column("t_ns").to_numpy(),
        np.c_[pose.column("x").to_numpy(), pose.column("y").to_numpy()],
        pose.column("yaw").to_numpy(),
        config.vehicle.track_m,
        config.model.wheel_window_radius_m + config.project.near_path_margin_m,
    )


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


SPEC = Stage(
    STAGE,
    "log",
    needs=(
        Need("laser", "ingest"),
        Need("lidar", "ingest", optional=True),  # 3-D lidar logs only
        Need("tf_static", "ingest", optional=True),
        Need("pose", "pose"),
    ),
    makes=("points",),
    hashed=hashed_sections,  # what it reads depends on [project] keep
    settings=ProjectSettings,
    check=_require_scanner,
    compute=_compute,
    recall=_recall,
    rows=("points",),
)


__all__ = [
    "LASER_COLUMNS",
    "SPEC",
    "STAGE",
    "Counts",
    "PoseStream",
    "PoseWindow",
    "PreparedBatch",
    "ProjectResult",
    "ProjectSettings",
    "ScanBatch",
    "prepare_batch",
    "project_batch",
    "project_prepared",
]

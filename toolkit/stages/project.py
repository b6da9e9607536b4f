"""Project stage: laser scans + pose -> the 3-D point cloud ``points.parquet`` (paper sect. 3).

Every return of every scan becomes a world point, placed with the pose *at the beam's own
time* and the laser's mount (``base_link_from_laser``, from ``tf_static.json`` by the scan's
``frame_id``, :func:`~toolkit.mounts.frame_mounts`)::

    t_b       = t_scan + b * time_increment                      (ROS LaserScan: stamp = beam 0)
    theta_b   = angle_min + b * angle_increment
    p_laser   = r_b (cos theta_b, sin theta_b, 0)
    p_world   = p_world_base(t_b) + R_world_base(t_b) (R_base_laser p_laser + t_base_laser)

``p_world_base`` is interpolated linearly between the two pose rows around ``t_b`` and
``R_world_base`` on the rotation group (:class:`scipy.spatial.transform.Slerp`: the constant
angular velocity arc between the two attitudes, which per-angle interpolation of roll, pitch
and yaw is not; it also never wraps yaw the long way round). The pose is the causal filter
output, what the vehicle knew while driving, as the paper projects with. Each point keeps its
laser, beam, range, scan time (``scan_t_ns``) and the time since that laser's previous scan
(``scan_dt_s``, NaN for a laser's first scan), and the roll and pitch rates at its time (the
paper's gamma and psi features, eq. 1; its tau is ``t_ns``).

Dropped and counted by reason (manifest ``rejects``; a warning on the terminal when any
are): ``bad_scan`` (every return of a scan whose angles or ``time_increment`` are not
finite), ``no_return`` (NaN/inf range), ``out_of_range`` (outside the scan's ``[range_min,
range_max]``), ``no_pose`` (before the first or after the last pose row, or inside a gap of
the pose longer than :data:`MAX_POSE_GAP_S`: no estimate to place it with) and ``no_mount``
(a laser whose frame the log's static transforms do not place on the vehicle).

Memory is bounded: scans are read :data:`SCAN_BATCH` at a time and the pose is streamed
alongside them (:class:`PoseStream`), so neither the scans nor the cloud of a long log is ever
whole in memory. Points are written in scan order (scans by time, beams in order).
"""

from __future__ import annotations

import json
import logging
import shutil
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from toolkit.analysis.fig4 import write_fig4
from toolkit.analysis.scan_agreement import ScanAgreement
from toolkit.analysis.truth_terrain import (
    TrueGround,
    ZErrorAccumulator,
    true_ground,
    write_z_error,
)
from toolkit.config import (
    ModelConfig,
    PipelineConfig,
    ProjectConfig,
    TopicsConfig,
    VehicleConfig,
)
from toolkit.errors import StageError
from toolkit.fusion.rotations import euler_to_rot
from toolkit.layout import LogFiles, log_file_name
from toolkit.mounts import Mount, frame_mounts
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.tableio import TableWriter, iter_table_batches, read_table, read_table_metadata
from toolkit.timewindow import TimeWindow
from toolkit.tyre_paths import META_KEPT_WITHIN_M, NearPath
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

STAGE = "project"
OUTPUT = log_file_name("points")
#: Configuration sections projection reads: the vehicle (its base frame, for the mounts; its
#: track, for the tyres' paths) and which points to keep; with ``keep = "near_path"`` also
#: the tables' radius around a tyre (:func:`stage_config_hash`).
CONFIG_SECTIONS = ("vehicle", "project")
#: Scans per read batch (5 lasers x 181 beams: ~360 k points, ~40 MB of arrays in flight).
SCAN_BATCH = 2_000
#: Points projected at a time within a batch: small enough that the ~40 temporary arrays of
#: the arithmetic stay in the processor's cache (32 k points: 256 kB each), large enough that
#: numpy's per-call overhead is small. 32 k ran 3.2x faster than a whole batch at once; 16 k
#: and 8 k slower again (measured, ``PoseWindow.transform``).
POINT_CHUNK = 32_768
#: The cloud's columns whose row groups carry min/max statistics: those a reader selects
#: points by (time, laser, place). The others' statistics cost 8 % of the writing (measured:
#: 10.2 against 9.4 M rows/s), and writing bounds the stage on long logs.
POINT_STATISTICS = ("t_ns", "scan_t_ns", "laser", "x", "y")
#: Threads projecting batches at once: the machine's two cores (reading and writing, in
#: pyarrow, run beside them outside the GIL too).
WORKERS = 2
#: Pose rows per read batch.
POSE_BATCH = 65_536
#: Longest interval between two pose rows a point may be interpolated across, s. The pose is
#: written at 100 Hz and has holes only where its IMU had gaps (no estimate there).
MAX_POSE_GAP_S = 0.05
#: Fig. 4 is accumulated over the scans of the log's first this-many seconds: all their
#: pairs up to 10 s apart, from one stretch of driving (as the paper's figure is), at a bounded
#: cost (~1 us per point, more than projecting it; ~8 M points here). Sampling windows spread
#: over the whole log instead changed the fitted slope of the sample log from 2.4 to 4.5 cm/s
#: (long-dt pairs lost at every window's edge), so the figure is of one contiguous stretch.
FIG4_SECONDS = 120.0
#: The z error against the true terrain (simulated logs) from every this-many-th point: the
#: route coordinates of a point cost ~1 us (measured: 0.6 s of the projecting threads for
#: the 650 k of a 10-minute log); 1/64 of all the sample log's points gave the same
#: per-laser medians as all of them to within a millimetre.
Z_ERROR_STRIDE = 64
#: ... lying on every this-many-th tile of the simulated terrain (51.2 m of road; ~80 k
#: points for ten minutes of driving, ~470 k for an hour). The terrain is synthesised where
#: it is first asked about (~115 ms for a tile alone, measured, under the lock the lazy
#: terrain needs), so the check samples *stretches of road*, each seen by every laser at
#: every range as the vehicle approaches it, at one tile's cost each: ~1.8 s of terrain for
#: a 10-minute log, about what sampling every 8th batch of scans cost (their points span
#: three tiles each), without holding the lock for three tiles at a time.
Z_ERROR_TILE_EVERY = 8
#: ... or closer, so that a short route still has this many checked stretches (the sample
#: log's 0.7 km: every tile).
Z_ERROR_FEWEST_STRETCHES = 15
#: Batches handed to the Fig. 4 thread at most, the one it is working on included (each
#: ~30 MB of points).
FIGURE_QUEUE = 2
#: How far behind the latest request the pose stream keeps rows, and how far a request may
#: reach back before the scans count as out of order, ns.
KEEP_BEHIND_NS = 1_000_000_000
#: Reasons a return is dropped, in the order they are checked.
REJECT_REASONS = ("bad_scan", "no_return", "out_of_range", "no_mount", "no_pose")
POSE_COLUMNS = ("t_ns", "x", "y", "z", "roll", "pitch", "yaw", "roll_rate", "pitch_rate")
LASER_COLUMNS = (
    "t_ns",
    "laser",
    "angle_min",
    "angle_increment",
    "time_increment",
    "ranges",
    "range_min",
    "range_max",
    "frame_id",
)


@dataclass(frozen=True)
class ProjectResult:
    """What :func:`run_project` did for one log."""

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
    """What projection reads of ``config`` (a radius only when it cuts by one)."""
    if config.project.keep == "near_path":
        return (*CONFIG_SECTIONS, "model.wheel_window_radius_m")
    # Keeping every point, the margin is not read: changing it leaves the cloud as it is.
    return ("vehicle", "project.keep")


# --------------------------------------------------------------------------------------
# The pose, streamed alongside the scans
# --------------------------------------------------------------------------------------


@dataclass
class PoseWindow:
    """Pose rows covering a stretch of time: ``t_ns`` (K,), ``position`` (K, 3) m,
    ``rotation`` (K rotations, world_from_base), ``rates`` (K, 2) roll and pitch rate rad/s."""

    t_ns: IntArray
    position: FloatArray
    rotation: Rotation
    rates: FloatArray

    def at(self, t_ns: IntArray) -> tuple[IntArray, FloatArray, NDArray[np.bool_]]:
        """Where the pose is defined at times ``t_ns`` (N,) and how to interpolate it there:
        the index ``i`` (N,) of the row before, the fraction (N,) of the way to row ``i + 1``,
        and a mask (N,) of the times it is defined at (inside the window, not across a gap
        longer than :data:`MAX_POSE_GAP_S`)."""
        t = self.t_ns
        if t.size < 2:  # nothing to interpolate between: the pose is defined nowhere
            return np.zeros(t_ns.size, np.int64), np.zeros(t_ns.size), np.zeros(t_ns.size, bool)
        i = np.clip(np.searchsorted(t, t_ns, side="right") - 1, 0, t.size - 2)
        inside = (t_ns >= t[0]) & (t_ns <= t[-1])
        step = t[i + 1] - t[i]
        ok = inside & (step > 0) & (step <= int(MAX_POSE_GAP_S * 1e9))
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.clip((t_ns - t[i]) / step.astype(np.float64), 0.0, 1.0)
        frac[~ok] = 0.0
        return i, frac, ok

    def transform(
        self, t_ns: IntArray, p_base: FloatArray
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Points ``p_base`` (3, N) in base_link at times ``t_ns`` (N,) -> world (3, N), the
        roll and pitch rates there (2, N), and the mask (N,) of points the pose is defined at.

        Position and rates are interpolated linearly; the attitude on the rotation group,
        ``R(t) = R_i exp([f r_i]x)`` with ``r_i = log(R_i^T R_i+1)`` (scipy, once per pose
        interval) and ``f`` the fraction of the way from row ``i`` to ``i + 1``: exactly
        scipy's :class:`~scipy.spatial.transform.Slerp` (a test checks they agree). Per
        point it is evaluated column-wise, Rodrigues' formula for ``exp([w]x) v`` with
        ``w = f r_i``, ``theta = |w|``::

            exp([w]x) v = v + a (w x v) + b w x (w x v),   a = sin(theta) / theta,
                                                           b = (1 - cos(theta)) / theta^2

        then ``R_i``. Between two pose rows 10 ms apart the body turns by milliradians, so
        ``a`` and ``b`` come from their Taylor series (:func:`_rodrigues_ab`) and the
        trigonometry runs only on the rare large turns. Everything a point needs from its
        interval (``r_i``, ``R_i``, position, rates: 22 numbers) is gathered from one
        (22, K - 1) table, a row at a time (numpy's one-dimensional ``take`` is several times
        faster than a ``take`` along the table's second axis). Composing
        N scipy rotations instead costs ~1 us per point (measured), several times all of this.
        """
        i, frac, ok = self.at(t_ns)
        if self.t_ns.size < 2:
            return np.zeros_like(p_base), np.zeros((2, t_ns.size)), ok
        g = [np.take(row, i) for row in self.interval_table]  # 22 x (N,)
        wx, wy, wz = g[0] * frac, g[1] * frac, g[2] * frac
        a, b = _rodrigues_ab(wx * wx + wy * wy + wz * wz)
        vx, vy, vz = p_base
        cx, cy, cz = wy * vz - wz * vy, wz * vx - wx * vz, wx * vy - wy * vx
        ux = vx + a * cx + b * (wy * cz - wz * cy)
        uy = vy + a * cy + b * (wz * cx - wx * cz)
        uz = vz + a * cz + b * (wx * cy - wy * cx)
        world = np.empty_like(p_base)
        for row in range(3):
            m0, m1, m2 = g[3 + 3 * row], g[4 + 3 * row], g[5 + 3 * row]
            world[row] = m0 * ux + m1 * uy + m2 * uz + g[12 + row] + frac * g[15 + row]
        rates = np.stack([g[18] + frac * g[20], g[19] + frac * g[21]])
        return world, rates, ok

    @cached_property
    def interval_table(self) -> FloatArray:
        """Per pose interval ``i`` (K - 1 columns): rows 0-2 ``r_i``, 3-11 ``R_i`` row-major,
        12-14 ``p_i``, 15-17 ``p_i+1 - p_i``, 18-19 the rates at ``i``, 20-21 their change.
        Computed once per window."""
        k = self.t_ns.size - 1
        table = np.empty((22, k))
        table[0:3] = (self.rotation[:-1].inv() * self.rotation[1:]).as_rotvec().T
        table[3:12] = self.rotation.as_matrix()[:-1].reshape(k, 9).T
        table[12:15] = self.position[:-1].T
        table[15:18] = np.diff(self.position, axis=0).T
        table[18:20] = self.rates[:-1].T
        table[20:22] = np.diff(self.rates, axis=0).T
        return table


#: Below this theta^2 (theta < 0.02 rad) the series of :func:`_rodrigues_ab` to theta^4 is
#: exact to its next term, theta^6 / 5040 < 2e-14.
_SERIES_THETA2 = 4e-4


def _rodrigues_ab(theta2: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rodrigues' coefficients ``a = sin(theta)/theta`` and ``b = (1 - cos(theta))/theta^2``
    for ``theta2 = theta^2`` (N,): their Taylor series ``a = 1 - t/6 + t^2/120`` and
    ``b = 1/2 - t/24 + t^2/720`` (``t = theta^2``; error below 2e-14 for theta < 0.02), and the
    trigonometric forms only where theta is larger."""
    a = 1.0 + theta2 * (-1.0 / 6.0 + theta2 * (1.0 / 120.0))
    b = 0.5 + theta2 * (-1.0 / 24.0 + theta2 * (1.0 / 720.0))
    large = np.flatnonzero(theta2 >= _SERIES_THETA2)
    if large.size:
        t2 = theta2[large]
        theta = np.sqrt(t2)
        a[large] = np.sin(theta) / theta
        b[large] = (1.0 - np.cos(theta)) / t2
    return a, b


class PoseStream:
    """The pose table read forward in batches, giving the rows that cover each request.

    Requests must come in time order (their first times non-decreasing, as scans sorted by
    time give); rows before the one preceding a request's first time are let go, so memory
    holds about one batch of scans' worth of pose.
    """

    def __init__(self, path: Path, schema_name: str = "pose") -> None:
        """Stream ``path`` (a ``pose`` or ``truth_pose`` table)."""
        self._path = path
        # truth_pose has the pose's columns and frame: a check can project with the truth.
        self._rows = TimeWindow(path, schema_name, columns=POSE_COLUMNS, batch_rows=POSE_BATCH)
        self._last_lo: int | None = None

    def window(self, t_lo_ns: int, t_hi_ns: int) -> PoseWindow:
        """Pose rows from the last one at or before ``t_lo_ns`` to the first at or after
        ``t_hi_ns`` (fewer at the ends of the table)."""
        if self._last_lo is not None and t_lo_ns < self._last_lo - KEEP_BEHIND_NS:
            raise StageError(
                "scans are not in time order (the laser table ingest writes is); "
                "run `terrain ingest --overwrite`",
                path=self._path,
            )
        self._last_lo = t_lo_ns if self._last_lo is None else max(self._last_lo, t_lo_ns)
        # Rows are let go only KEEP_BEHIND_NS behind the request: beam times of the next
        # batch may start a little before this one's (a negative time_increment, lasers
        # whose stamps are not quite in order).
        self._rows.forget_before(self._last_lo - KEEP_BEHIND_NS)
        c = self._rows.rows(t_lo_ns, t_hi_ns)
        rpy = np.stack([c["roll"], c["pitch"], c["yaw"]], axis=1).astype(np.float64)
        rotation = Rotation.from_matrix(euler_to_rot(rpy)) if rpy.shape[0] else Rotation.identity(0)
        return PoseWindow(
            t_ns=np.asarray(c["t_ns"], dtype=np.int64),
            position=np.stack([c["x"], c["y"], c["z"]], axis=1).astype(np.float64),
            rotation=rotation,
            rates=np.stack([c["roll_rate"], c["pitch_rate"]], axis=1).astype(np.float64),
        )


# --------------------------------------------------------------------------------------
# Projection of a batch of scans
# --------------------------------------------------------------------------------------


@dataclass
class ScanBatch:
    """Scans flattened to one row per beam: ``scan`` (M,) index of each beam's scan in the
    batch, ``beam`` (M,), ``range_m`` (M,) float32, plus the per-scan arrays (S,)."""

    t_ns: IntArray
    laser: pa.Array
    #: Each scan's laser and frame as a code (S,) into the distinct names of the batch.
    laser_code: IntArray
    laser_names: list[str]
    frame_code: IntArray
    frame_names: list[str]
    angle_min: FloatArray
    angle_increment: FloatArray
    time_increment: FloatArray
    range_min: FloatArray
    range_max: FloatArray
    scan: IntArray
    beam: IntArray
    range_m: NDArray[np.float32]

    @classmethod
    def from_record_batch(cls, batch: pa.RecordBatch) -> ScanBatch:
        ranges = batch.column("ranges")
        offsets = ranges.offsets.to_numpy()
        if ranges.offset or offsets[0]:  # a sliced list array: rebase its offsets
            offsets = offsets - offsets[0]
        lengths = np.diff(offsets)
        n_scans = lengths.size
        scan = np.repeat(np.arange(n_scans, dtype=np.int64), lengths)
        beam = np.arange(scan.size, dtype=np.int64) - np.repeat(offsets[:-1], lengths)
        values = pc.list_flatten(ranges).to_numpy(zero_copy_only=False).astype(np.float32)

        def codes(name: str) -> tuple[IntArray, list[str]]:
            """A string column as codes into its distinct values (a null is "")."""
            encoded = pc.dictionary_encode(pc.fill_null(batch.column(name), ""))
            names = [str(v) for v in encoded.dictionary.to_pylist()]
            return np.asarray(encoded.indices.to_numpy(zero_copy_only=False), np.int64), names

        laser_code, laser_names = codes("laser")
        frame_code, frame_names = codes("frame_id")

        def f64(name: str, fill: float) -> FloatArray:
            col = batch.column(name)
            return np.asarray(pc.fill_null(col, fill).to_numpy(zero_copy_only=False), np.float64)

        return cls(
            t_ns=np.asarray(batch.column("t_ns").to_numpy(), dtype=np.int64),
            laser=batch.column("laser"),
            laser_code=laser_code,
            laser_names=laser_names,
            frame_code=frame_code,
            frame_names=frame_names,
            angle_min=f64("angle_min", np.nan),
            angle_increment=f64("angle_increment", np.nan),
            time_increment=f64("time_increment", 0.0),
            range_min=f64("range_min", 0.0),
            range_max=f64("range_max", np.inf),
            scan=scan,
            beam=beam,
            range_m=values,
        )


@dataclass
class Counts:
    """Running totals of a projection."""

    points: int = 0
    scans: int = 0
    rejects: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REJECT_REASONS, 0))

    def add(self, other: Counts) -> None:
        """Add another batch's counts to these."""
        self.points += other.points
        self.scans += other.scans
        for reason, n in other.rejects.items():
            self.rejects[reason] = self.rejects.get(reason, 0) + n


class _ZSample(NamedTuple):
    """A batch's z-error sample (:func:`_z_sample`): each point's laser, range and z error
    against the true terrain, m (K,)."""

    laser: pa.Array
    range_m: FloatArray
    z_error_m: FloatArray


@dataclass(frozen=True)
class PreparedBatch:
    """A batch of scans with everything its projection needs from the scans before it (the
    time since each laser's previous scan) and from the pose stream (the pose rows it spans),
    so projecting it (:func:`project_prepared`) is a pure function any thread may run."""

    scans: ScanBatch
    #: Time since the same laser's previous scan (S,) s, NaN for a laser's first scan.
    scan_dt: FloatArray
    #: Each scan's mount (S,) as an index into ``mount_list``, -1 for none.
    scan_mount: IntArray
    mount_list: tuple[Mount, ...]
    #: False (S,) for a scan whose angles or timing are not finite.
    good_scan: NDArray[np.bool_]
    window: PoseWindow


def prepare_batch(
    scans: ScanBatch,
    mounts: dict[str, Mount],
    poses: PoseStream,
    previous_scan_ns: dict[str, int],
) -> PreparedBatch:
    """The sequential part of projecting a batch, in scan order: ``previous_scan_ns`` (laser
    -> stamp of its last scan) is carried from batch to batch for ``scan_dt_s``, and the pose
    stream advances to the batch's time span."""
    n_scans = scans.t_ns.size
    scan_dt = np.full(n_scans, np.nan)
    for code, name in enumerate(scans.laser_names):  # per laser, not per scan or point
        rows = np.flatnonzero(scans.laser_code == code)
        if rows.size == 0:
            continue
        stamps = scans.t_ns[rows]
        # Differences in integer ns (stamps near 1e18 ns lose 256 ns as float64).
        scan_dt[rows[1:]] = np.diff(stamps) * 1e-9
        if name in previous_scan_ns:
            scan_dt[rows[0]] = (int(stamps[0]) - previous_scan_ns[name]) * 1e-9
        previous_scan_ns[name] = int(stamps[-1])
    mount_list = tuple(mounts.values())
    code_of = {m.frame: k for k, m in enumerate(mount_list)}
    frame_mount = np.array([code_of.get(f, -1) for f in scans.frame_names], dtype=np.int64)
    good_scan = (
        np.isfinite(scans.angle_min)
        & np.isfinite(scans.angle_increment)
        & np.isfinite(scans.time_increment)
    )
    # The pose rows the batch needs, from its scans' first and last beam times.
    lengths = np.bincount(scans.scan, minlength=n_scans)
    span_ns = np.where(good_scan, (lengths - 1).clip(0) * scans.time_increment * 1e9, 0.0)
    if n_scans and scans.range_m.size:
        # A nanosecond beyond either end: the beams' offsets are rounded, the span is not.
        t_lo = int((scans.t_ns + np.minimum(span_ns, 0.0).astype(np.int64)).min()) - 1
        t_hi = int((scans.t_ns + np.maximum(span_ns, 0.0).astype(np.int64)).max()) + 1
        window = poses.window(t_lo, t_hi)
    else:
        window = PoseWindow(
            np.zeros(0, np.int64), np.zeros((0, 3)), Rotation.identity(0), np.zeros((0, 2))
        )
    return PreparedBatch(
        scans, scan_dt, frame_mount[scans.frame_code], mount_list, good_scan, window
    )


def project_prepared(batch: PreparedBatch) -> tuple[pa.Table, Counts]:
    """Project a prepared batch: its points table and its counts (a pure function: safe to
    run for several batches at once in threads, numpy releasing the GIL in its loops)."""
    scans = batch.scans
    counts = Counts(scans=scans.t_ns.size)
    if scans.range_m.size == 0:
        return _points_table([], scans), counts
    directions, origins, offset, scan_geometry = _beam_directions(
        scans, batch.scan_mount, batch.mount_list
    )
    scan_key = np.take(offset, scan_geometry)
    chunks = [
        _project_chunk(batch, slice(lo, lo + POINT_CHUNK), directions, origins, scan_key, counts)
        for lo in range(0, scans.range_m.size, POINT_CHUNK)
    ]
    return _points_table(chunks, scans), counts


def project_batch(
    scans: ScanBatch,
    mounts: dict[str, Mount],
    poses: PoseStream,
    previous_scan_ns: dict[str, int],
    counts: Counts,
) -> pa.Table:
    """Project one batch of scans (see the module docstring): :func:`prepare_batch` then
    :func:`project_prepared`; returns the points table and adds to ``counts``."""
    table, batch_counts = project_prepared(prepare_batch(scans, mounts, poses, previous_scan_ns))
    counts.add(batch_counts)
    return table


def _project_chunk(
    batch: PreparedBatch,
    rows: slice,
    directions: FloatArray,
    origins: FloatArray,
    scan_key: IntArray,
    counts: Counts,
) -> dict[str, NDArray[Any]]:
    """The points of the flattened beams ``rows`` of a batch, as columns (the per-scan
    arrays (S,) are the batch's). Done a chunk at a time so every temporary array stays in
    the processor's cache: the same arithmetic over a whole 360 k-point batch runs about three
    times slower (measured), its temporaries going to main memory and back."""
    scans = batch.scans
    s, b, r = scans.scan[rows], scans.beam[rows], scans.range_m[rows]
    usable = np.take(batch.good_scan, s)
    finite = np.isfinite(r)
    counts.rejects["bad_scan"] += int(r.size - np.count_nonzero(usable))
    counts.rejects["no_return"] += int(np.count_nonzero(usable & ~finite))
    finite &= usable
    with np.errstate(invalid="ignore"):
        in_range = finite & (r >= np.take(scans.range_min, s)) & (r <= np.take(scans.range_max, s))
    counts.rejects["out_of_range"] += int(np.count_nonzero(finite & ~in_range))
    mounted = in_range & (np.take(batch.scan_mount, s) >= 0)
    counts.rejects["no_mount"] += int(np.count_nonzero(in_range & ~mounted))
    if not mounted.all():  # (gathers are the costliest step here: skipped when all stay)
        keep = np.flatnonzero(mounted)
        s, b, r = np.take(s, keep), np.take(b, keep), np.take(r, keep)
    r = r.astype(np.float64)

    # Beam times: stamp + beam x time_increment (ROS LaserScan: the stamp is beam 0's time).
    offset_ns = np.round(b * np.take(scans.time_increment, s) * 1e9).astype(np.int64)
    t_ns = np.take(scans.t_ns, s) + offset_ns
    # Beam directions and origins in base_link, per scan geometry and beam (see
    # _beam_directions), gathered per point.
    key = np.take(scan_key, s) + b
    p_base = np.empty((3, r.size))
    for k in range(3):
        p_base[k] = r * np.take(directions[k], key) + np.take(origins[k], key)
    p_world, rates, ok = batch.window.transform(t_ns, p_base)
    ok &= np.isfinite(p_world).all(axis=0)  # never a NaN point written as a good one
    counts.rejects["no_pose"] += int(ok.size - np.count_nonzero(ok))
    columns = {
        "t_ns": t_ns,
        "scan": s,
        "beam": b.astype(np.int32),
        "range": r.astype(np.float32),
        "x": p_world[0],
        "y": p_world[1],
        "z": p_world[2],
        "roll_rate": rates[0],
        "pitch_rate": rates[1],
    }
    if not ok.all():
        sel = np.flatnonzero(ok)
        columns = {c: np.take(v, sel) for c, v in columns.items()}
    counts.points += columns["t_ns"].size
    columns["scan_t_ns"] = np.take(scans.t_ns, columns["scan"])
    columns["scan_dt_s"] = np.take(batch.scan_dt, columns["scan"])
    return columns


def _points_table(chunks: list[dict[str, NDArray[Any]]], scans: ScanBatch) -> pa.Table:
    """The points of a batch's chunks as one table of the points schema's columns, a record
    batch per chunk (numpy's arrays are taken as they are, not copied)."""
    if not chunks:
        chunks = [{c: np.zeros(0, dt) for c, dt in _CHUNK_DTYPES.items()}]
    # The laser as codes into the batch's few names: Parquet's writer then takes the
    # dictionary as it is instead of hashing a string per point (writing the cloud 1.7x
    # faster, measured), and no string is copied per point.
    lasers = pa.array(scans.laser_names, pa.string())
    return pa.Table.from_batches(
        [
            pa.record_batch(
                {
                    "t_ns": pa.array(ch["t_ns"], pa.int64()),
                    "laser": pa.DictionaryArray.from_arrays(
                        pa.array(np.take(scans.laser_code, ch["scan"]), pa.int32()), lasers
                    ),
                    "beam": pa.array(ch["beam"], pa.int32()),
                    "range": pa.array(ch["range"], pa.float32()),
                    **{c: pa.array(ch[c], pa.float64()) for c in ("x", "y", "z")},
                    "roll_rate": pa.array(ch["roll_rate"], pa.float64()),
                    "pitch_rate": pa.array(ch["pitch_rate"], pa.float64()),
                    "scan_t_ns": pa.array(ch["scan_t_ns"], pa.int64()),
                    "scan_dt_s": pa.array(ch["scan_dt_s"], pa.float64()),
                }
            )
            for ch in chunks
        ]
    )


_CHUNK_DTYPES: dict[str, type] = {
    "t_ns": np.int64,
    "scan": np.int64,
    "beam": np.int32,
    "range": np.float32,
    "x": np.float64,
    "y": np.float64,
    "z": np.float64,
    "roll_rate": np.float64,
    "pitch_rate": np.float64,
    "scan_t_ns": np.int64,
    "scan_dt_s": np.float64,
}


def _beam_directions(
    scans: ScanBatch,
    scan_mount: IntArray,
    mount_list: tuple[Mount, ...],
) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
    """Unit beam directions (3, D) and origins (3, D) in base_link for every (scan
    geometry, beam), the first row ``offset`` (G,) of each geometry's beams and each scan's
    geometry (S,): a point's row is ``offset[geometry[scan]] + beam``. A geometry is a scan's
    (mount, angle_min, angle_increment); a laser keeps one, so D is about its beam count."""
    geometry = np.stack(
        [scan_mount.astype(np.float64), scans.angle_min, scans.angle_increment], axis=1
    )
    unique, scan_geometry = np.unique(geometry, axis=0, return_inverse=True)
    scan_geometry = scan_geometry.reshape(-1)
    lengths = np.bincount(scans.scan, minlength=scans.t_ns.size)
    beams = np.zeros(unique.shape[0], dtype=np.int64)
    np.maximum.at(beams, scan_geometry, lengths)
    offset = np.concatenate([[0], np.cumsum(beams)[:-1]]).astype(np.int64)
    directions = np.zeros((3, int(beams.sum())))
    origins = np.zeros((3, int(beams.sum())))
    for g, (code, angle_min, increment) in enumerate(unique):  # per geometry, not per point
        if code < 0 or not (np.isfinite(angle_min) and np.isfinite(increment)):
            continue  # no mount or no geometry: its points are dropped before they are placed
        mount = mount_list[int(code)]
        theta = angle_min + np.arange(beams[g]) * increment
        rows = slice(int(offset[g]), int(offset[g] + beams[g]))
        directions[:, rows] = (np.c_[np.cos(theta), np.sin(theta)] @ mount.rotation[:, :2].T).T
        origins[:, rows] = np.asarray(mount.translation_m, dtype=np.float64)[:, None]
    return directions, origins, offset, scan_geometry


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


def run_project(
    workspace: Workspace, log_id: str, config: PipelineConfig, *, overwrite: bool = False
) -> ProjectResult:
    """Project one log's scans into the world (see the module docstring)."""
    result = run_stage(SPEC, workspace, config, log_id=log_id, overwrite=overwrite)
    return cast(ProjectResult, result)


def _require_lasers(files: LogFiles, config: ProjectSettings) -> None:
    """StageError when the log has no laser to project."""
    if config.topics.lasers == () or not files.laser.is_file():
        raise StageError(
            "projection needs the lasers role, and this log has none (no laser.parquet; "
            "[topics] lasers accepts sensor_msgs/msg/LaserScan topics)",
            path=files.laser,
        )


def _recall(last: Recalled) -> ProjectResult:
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


def _compute(call: Call) -> Made:
    """Project the scans of the log in ``call.files`` (the module docstring)."""
    config: ProjectSettings = call.settings
    log_dir, log_id, start = call.files.dir, call.log_id, call.start
    manifest, cfg_hash, out_path = call.manifest, call.config_hash, call.files.points
    laser_path, pose_path, tf_path = call.files.laser, call.files.pose, call.files.tf_static
    _require_disk_for_cloud(laser_path, config)
    timings = dict.fromkeys(("read", "project", "write", "figures"), 0.0)
    frames = _laser_frames(laser_path)
    mounts, mount_warnings = frame_mounts(tf_path, config.vehicle.base_frame, frames)
    warnings = list(mount_warnings)
    pose_meta = read_table_metadata(pose_path)
    frame_meta: dict[str, str] = {
        k: pose_meta[k] for k in ("frame_id", "enu_origin", "local_origin") if k in pose_meta
    }
    sha = json.loads(json.dumps(manifest.read().get("source", {}))).get("sha256", "")
    poses = PoseStream(pose_path)
    near_path = _near_path(pose_path, config)
    if near_path is not None:
        frame_meta[META_KEPT_WITHIN_M] = repr(near_path.distance_m)
    far_from_path = 0
    # The paper's Fig. 4 from the log itself, and on simulated logs the points' z error
    # against the true terrain, accumulated batch by batch as the points are made.
    agreement = ScanAgreement()
    try:
        ground = true_ground(log_dir)
    except StageError as exc:  # a simulated log posed without GPS: no tie to the truth
        ground = None
        warnings.append(f"no z error against the true terrain: {exc}")
    z_error = ZErrorAccumulator() if ground is not None else None
    z_every = (
        ground.stretch_every(Z_ERROR_FEWEST_STRETCHES, Z_ERROR_TILE_EVERY)
        if ground is not None
        else Z_ERROR_TILE_EVERY
    )
    counts = Counts()
    previous_scan_ns: dict[str, int] = {}
    fig4_until_ns: int | None = None
    batches = iter_table_batches(laser_path, "laser", columns=LASER_COLUMNS, batch_rows=SCAN_BATCH)
    with TableWriter(
        out_path,
        "points",
        source_sha256=sha,
        config_hash=cfg_hash,
        extra_metadata=frame_meta,
        bulk=True,
        statistics=POINT_STATISTICS,
    ) as writer:
        # Batches are prepared in order here (the pose stream and each laser's previous
        # scan are sequential), projected by a pool of threads (numpy and the truth lookup
        # release the GIL in their loops), then written here and handed to Fig. 4's own
        # thread, in order: the output is the same as projecting one batch after another,
        # and reading, projecting, writing (pyarrow's encoding and compression, also outside
        # the GIL) and Fig. 4 overlap on the machine's cores. At most WORKERS + 1 batches
        # are in flight and FIGURE_QUEUE with Fig. 4, so memory stays bounded. (A
        # separate writer thread was tried: no faster on two cores, measured; Fig. 4 on its
        # own thread took the 10-minute log's loop from 10.9-11.5 s to 10.5-10.9 s.)
        lock = threading.Lock()  # the simulated world builds its tiles lazily

        def work(
            prepared: PreparedBatch,
        ) -> tuple[pa.Table, pa.Table, Counts, _ZSample | None, float]:
            t0 = time.perf_counter()
            table, batch_counts = project_prepared(prepared)
            sample = None
            if ground is not None and table.num_rows:
                sample = _z_sample(ground, table, lock, z_every)
            kept = table
            if near_path is not None:
                x, y = table.column("x").to_numpy(), table.column("y").to_numpy()
                kept = table.filter(pa.array(near_path.mask(x, y)))
            return table, kept, batch_counts, sample, time.perf_counter() - t0

        def finish(
            future: Future[tuple[pa.Table, pa.Table, Counts, _ZSample | None, float]],
        ) -> None:
            nonlocal fig4_until_ns, far_from_path
            table, kept, batch_counts, sample, seconds = future.result()
            timings["project"] += seconds
            counts.add(batch_counts)
            far_from_path += table.num_rows - kept.num_rows
            t = time.perf_counter()
            # Fig. 4 and the z error below see every point projected; the cloud keeps those
            # asked for.
            writer.write(kept)
            timings["write"] += time.perf_counter() - t
            t = time.perf_counter()
            if table.num_rows:
                first_ns = int(pc.min(table.column("scan_t_ns")).as_py())
                if fig4_until_ns is None:
                    fig4_until_ns = first_ns + int(FIG4_SECONDS * 1e9)
                if first_ns < fig4_until_ns:
                    # Fig. 4 runs beside the writing, on a thread of its own (the batches
                    # in order, as it needs); at most FIGURE_QUEUE of them are handed to
                    # it at once. (So timings["figures"] is this thread's waiting for it,
                    # not Fig. 4's own work.)
                    figure_jobs.append(figure_pool.submit(agreement.feed, table))
                    while len(figure_jobs) > FIGURE_QUEUE:
                        figure_jobs.popleft().result()
            if z_error is not None and sample is not None:
                z_error.feed(sample.laser, sample.range_m, sample.z_error_m)
            timings["figures"] += time.perf_counter() - t

        loop_start = time.perf_counter()
        pending: deque[Future[tuple[pa.Table, pa.Table, Counts, _ZSample | None, float]]] = deque()
        figure_jobs: deque[Future[None]] = deque()
        with (
            ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="project") as pool,
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="fig4") as figure_pool,
        ):
            try:
                while True:
                    t = time.perf_counter()
                    batch = next(batches, None)
                    if batch is None:
                        break
                    scans = ScanBatch.from_record_batch(batch)
                    prepared = prepare_batch(scans, mounts, poses, previous_scan_ns)
                    timings["read"] += time.perf_counter() - t
                    pending.append(pool.submit(work, prepared))
                    if len(pending) > WORKERS:
                        finish(pending.popleft())
                while pending:
                    finish(pending.popleft())
                while figure_jobs:
                    figure_jobs.popleft().result()
            finally:
                for future in pending:  # an error: let nothing run on behind it
                    future.cancel()
                for job in figure_jobs:
                    job.cancel()
        timings["loop"] = time.perf_counter() - loop_start
    t = time.perf_counter()
    fig4 = agreement.result()
    figure_files = [p.name for p in write_fig4(fig4, log_dir, log_id)]
    if z_error is not None:
        figure_files += [p.name for p in write_z_error(z_error.result(), log_dir, title=log_id)]
    timings["figures"] += time.perf_counter() - t
    fit = fig4.fit
    header = {
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
    dropped = {k: v for k, v in counts.rejects.items() if v}
    returns = counts.points + sum(counts.rejects.values())
    if dropped:
        warnings.append(
            f"{sum(dropped.values())} of {returns} returns dropped ("
            + ", ".join(f"{k} {v}" for k, v in dropped.items())
            + ")"
        )
    timings["total"] = time.perf_counter() - start
    outcome = ProjectResult(
        log_id,
        "projected",
        counts.points - far_from_path,
        counts.scans,
        dict(counts.rejects),
        time.perf_counter() - start,
        warnings=tuple(warnings),
        points_per_s=counts.points / max(timings["loop"], 1e-9),
        fig4=f"Fig. 4 {fit.describe()}",
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
        header=header,
    )


#: Bytes a point of the cloud takes on disk, measured on a 20-mile race (benchmarks/README.md,
#: "Disk"): every point kept (8.8), and per point projected when only those near the tyres'
#: paths are kept (13.6 bytes for each of the 11 % kept); rounded up.
CLOUD_BYTES_PER_RETURN = {"all": 9.0, "near_path": 1.6}


def _require_disk_for_cloud(laser_path: Path, config: ProjectSettings) -> None:
    """StageError, before anything is written, when the disk cannot hold the cloud: its
    size estimated from the scans' returns (the ``ranges`` values counted in the Parquet
    footer, not read) at :data:`CLOUD_BYTES_PER_RETURN`, against the free space beside it
    (with the old cloud's own size, which the new one replaces)."""
    meta = pq.ParquetFile(laser_path).metadata
    leaf = next(
        (
            j
            for j in range(meta.num_columns)
            if meta.schema.column(j).path.split(".")[0] == "ranges"
        ),
        None,
    )
    if leaf is None:
        return
    returns = sum(meta.row_group(i).column(leaf).num_values for i in range(meta.num_row_groups))
    need = returns * CLOUD_BYTES_PER_RETURN[config.project.keep]
    old = laser_path.with_name(OUTPUT)
    free = shutil.disk_usage(laser_path.parent).free + (old.stat().st_size if old.is_file() else 0)
    _log.info("the point cloud of %d returns will take about %.2f GB", returns, need / 1e9)
    if need > free:
        hint = (
            '; [project] keep = "near_path" keeps only the points the tables use, about a sixth'
            if config.project.keep == "all"
            else ""
        )
        raise StageError(
            f"the point cloud of {returns} laser returns needs about {need / 1e9:.2f} GB and "
            f"{free / 1e9:.2f} GB are free on this disk: make room{hint}",
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


def _z_sample(
    ground: TrueGround, table: pa.Table, lock: threading.Lock, every: int
) -> _ZSample | None:
    """The z-error sample of a batch's points ``table``: of every :data:`Z_ERROR_STRIDE`-th
    point, those on a checked stretch of road (every ``every``-th terrain tile,
    :meth:`~toolkit.analysis.truth_terrain.TrueGround.checked_stretch`), with their error
    against the true terrain (None: no point there). The terrain is built under ``lock``,
    one stretch at a time (a window across two stretches would build every tile between)."""
    some = table.take(pa.array(np.arange(0, table.num_rows, Z_ERROR_STRIDE)))
    xyz = np.stack([some.column(c).to_numpy() for c in "xyz"], axis=1)
    s, d, z = ground.route_coordinates(xyz)
    stretch = ground.checked_stretch(s, every)
    rows = np.flatnonzero(stretch >= 0)
    if rows.size == 0:
        return None
    error = np.empty(rows.size)
    for k in np.unique(stretch[rows]):
        on = np.flatnonzero(stretch[rows] == k)
        with lock:
            error[on] = z[rows[on]] - ground.terrain_height_m(s[rows[on]], d[rows[on]])
    return _ZSample(
        some.column("laser").take(pa.array(rows)), some.column("range").to_numpy()[rows], error
    )


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _laser_frames(laser_path: Path) -> list[str]:
    """The distinct ``frame_id`` of the scans (read as one small dictionary column)."""
    frames: set[str] = set()
    for batch in iter_table_batches(laser_path, "laser", columns=["frame_id"], batch_rows=65_536):
        frames.update(str(f or "") for f in pc.unique(batch.column("frame_id")).to_pylist())
    return sorted(frames)


SPEC = Stage(
    STAGE,
    "log",
    needs=(
        Need("laser", "ingest"),
        Need("tf_static", "ingest", optional=True),
        Need("pose", "pose"),
    ),
    makes=("points",),
    sections=CONFIG_SECTIONS,
    hashed=hashed_sections,
    settings=ProjectSettings,
    check=_require_lasers,
    compute=_compute,
    recall=_recall,
    rows=("points",),
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "STAGE",
    "ProjectSettings",
    "PoseStream",
    "PoseWindow",
    "ProjectResult",
    "ScanBatch",
    "project_batch",
    "run_project",
    "stage_config_hash",
]

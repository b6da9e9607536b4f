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
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from toolkit.analysis.scan_agreement import ScanAgreement, write_fig4
from toolkit.analysis.truth_terrain import ZErrorAccumulator, true_ground, write_z_error
from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import StageError
from toolkit.fusion.rotations import euler_to_rot
from toolkit.mounts import Mount, frame_mounts
from toolkit.stages.per_log import run_on_log
from toolkit.tableio import TableWriter, iter_table_batches, read_table_metadata
from toolkit.workspace import (
    Manifest,
    StageRecord,
    Workspace,
    check_up_to_date,
    digest_files,
    file_sha256,
    require_finished,
)

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

STAGE = "project"
OUTPUT = "points.parquet"
#: Configuration sections projection reads: the vehicle (its base frame, for the mounts).
CONFIG_SECTIONS = ("vehicle",)
#: Scans per read batch (5 lasers x 181 beams: ~360 k points, ~40 MB of arrays in flight).
SCAN_BATCH = 2_000
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
#: truth lookup costs ~3 us per point, and 1/64 of the sample log's points (65 k) gives the
#: same per-laser medians as all of them to within a millimetre.
Z_ERROR_STRIDE = 64
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

    def summary(self) -> str:
        """One line for people: points, scans, what was dropped and why."""
        parts = [f"{self.points} points from {self.scans} scans"]
        dropped = {k: v for k, v in self.rejects.items() if v}
        if dropped:
            parts.append("dropped " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
        if self.fig4:
            parts.append(self.fig4)
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return f"{self.log_id}: points {self.status.replace('_', ' ')} ({'; '.join(parts)})"


def stage_config_hash(config: PipelineConfig) -> str:
    return config_hash(config, sections=CONFIG_SECTIONS)


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

        then ``R_i`` (its 9 entries gathered per point). Composing N scipy rotations instead
        costs ~1 us per point (measured), several times all of this.
        """
        i, frac, ok = self.at(t_ns)
        if self.t_ns.size < 2:
            return np.zeros_like(p_base), np.zeros((2, t_ns.size)), ok
        rel = (self.rotation[:-1].inv() * self.rotation[1:]).as_rotvec()  # (K - 1, 3)
        wx, wy, wz = (np.take(rel[:, k], i) * frac for k in range(3))
        theta2 = wx * wx + wy * wy + wz * wz
        theta = np.sqrt(theta2)
        small = theta < 1e-4  # the series to O(theta^4): exact to 1e-18 there
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.where(small, 1.0 - theta2 / 6.0, np.sin(theta) / theta)
            b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(theta)) / theta2)
        vx, vy, vz = p_base
        cx, cy, cz = wy * vz - wz * vy, wz * vx - wx * vz, wx * vy - wy * vx
        ux = vx + a * cx + b * (wy * cz - wz * cy)
        uy = vy + a * cy + b * (wz * cx - wx * cz)
        uz = vz + a * cz + b * (wx * cy - wy * cx)
        m = np.ascontiguousarray(self.rotation.as_matrix().reshape(-1, 9).T)  # (9, K)
        world = np.empty_like(p_base)
        for row in range(3):
            m0, m1, m2 = (np.take(m[3 * row + col], i) for col in range(3))
            p0 = np.take(self.position[:, row], i)
            p1 = np.take(self.position[:, row], i + 1)
            world[row] = m0 * ux + m1 * uy + m2 * uz + p0 + frac * (p1 - p0)
        rates = np.empty((2, t_ns.size))
        for k in range(2):
            r0, r1 = np.take(self.rates[:, k], i), np.take(self.rates[:, k], i + 1)
            rates[k] = r0 + frac * (r1 - r0)
        return world, rates, ok


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
        self._batches: Iterator[pa.RecordBatch] = iter_table_batches(
            path, schema_name, columns=POSE_COLUMNS, batch_rows=POSE_BATCH
        )
        self._cols: dict[str, NDArray[Any]] = {c: np.zeros(0) for c in POSE_COLUMNS}
        self._cols["t_ns"] = np.zeros(0, dtype=np.int64)
        self._done = False
        self._last_lo: int | None = None

    def _pull(self) -> bool:
        batch = next(self._batches, None)
        if batch is None:
            self._done = True
            return False
        for c in POSE_COLUMNS:
            v = batch.column(c).to_numpy(zero_copy_only=False)
            self._cols[c] = np.concatenate([self._cols[c], v])
        return True

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
        while not self._done and (self._cols["t_ns"].size == 0 or self._cols["t_ns"][-1] < t_hi_ns):
            self._pull()
        t = self._cols["t_ns"]
        # Rows are let go only KEEP_BEHIND_NS behind the request: beam times of the next
        # batch may start a little before this one's (a negative time_increment, lasers
        # whose stamps are not quite in order).
        first = max(int(np.searchsorted(t, t_lo_ns - KEEP_BEHIND_NS, side="right")) - 1, 0)
        if first:
            self._cols = {c: v[first:] for c, v in self._cols.items()}
            t = self._cols["t_ns"]
        last = min(int(np.searchsorted(t, t_hi_ns, side="left")) + 1, t.size)
        c = {k: v[:last] for k, v in self._cols.items()}
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


def project_batch(
    scans: ScanBatch,
    mounts: dict[str, Mount],
    poses: PoseStream,
    previous_scan_ns: dict[str, int],
    counts: Counts,
) -> pa.Table:
    """Project one batch of scans (see the module docstring); returns the points table and
    adds to ``counts``. ``previous_scan_ns`` (laser -> stamp of its last scan) is carried
    from batch to batch for ``scan_dt_s``."""
    n_scans = scans.t_ns.size
    counts.scans += n_scans
    # Time since each laser's previous scan, carried across batches.
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

    s, b, r = scans.scan, scans.beam, scans.range_m
    # A scan whose geometry or timing is not finite places none of its returns.
    good_scan = (
        np.isfinite(scans.angle_min)
        & np.isfinite(scans.angle_increment)
        & np.isfinite(scans.time_increment)
    )
    usable = np.take(good_scan, s)
    counts.rejects["bad_scan"] += int((~usable).sum())
    finite = np.isfinite(r) & usable
    counts.rejects["no_return"] += int((usable & ~np.isfinite(r)).sum())
    with np.errstate(invalid="ignore"):
        in_range = finite & (r >= np.take(scans.range_min, s)) & (r <= np.take(scans.range_max, s))
    counts.rejects["out_of_range"] += int((finite & ~in_range).sum())
    # Each scan's laser mount as a small integer code (-1: none).
    mount_list = list(mounts.values())
    code_of = {m.frame: k for k, m in enumerate(mount_list)}
    frame_mount = np.array([code_of.get(f, -1) for f in scans.frame_names], dtype=np.int64)
    scan_mount = frame_mount[scans.frame_code]
    mounted = in_range & (np.take(scan_mount, s) >= 0)
    counts.rejects["no_mount"] += int((in_range & ~mounted).sum())
    keep = np.flatnonzero(mounted)
    s, b, r = np.take(s, keep), np.take(b, keep), np.take(r, keep).astype(np.float64)

    # Beam times: stamp + beam x time_increment (ROS LaserScan: the stamp is beam 0's time).
    offset_ns = np.round(b * np.take(scans.time_increment, s) * 1e9).astype(np.int64)
    t_ns = np.take(scans.t_ns, s) + offset_ns
    # Beam directions in base_link, R_base_laser (cos theta_b, sin theta_b, 0), computed once
    # per scan geometry (laser, angle_min, angle_increment) and beam, gathered per point.
    directions, origins, key = _beam_directions(scans, scan_mount, mount_list, s, b)
    p_base = np.empty((3, r.size))
    for k in range(3):
        p_base[k] = r * np.take(directions[:, k], key) + np.take(origins[:, k], key)
    if t_ns.size:
        window = poses.window(int(t_ns.min()), int(t_ns.max()))
        p_world, rates, ok = window.transform(t_ns, p_base)
        ok &= np.isfinite(p_world).all(axis=0)  # never a NaN point written as a good one
    else:
        p_world, rates, ok = np.zeros((3, 0)), np.zeros((2, 0)), np.zeros(0, bool)
    counts.rejects["no_pose"] += int((~ok).sum())
    sel = np.flatnonzero(ok)
    counts.points += sel.size
    s_sel = np.take(s, sel)
    return pa.table(
        {
            "t_ns": pa.array(np.take(t_ns, sel), pa.int64()),
            "laser": pc.take(scans.laser, pa.array(s_sel, pa.int64())),
            "beam": pa.array(np.take(b, sel).astype(np.int32), pa.int32()),
            "range": pa.array(np.take(r, sel).astype(np.float32), pa.float32()),
            "x": pa.array(np.take(p_world[0], sel), pa.float64()),
            "y": pa.array(np.take(p_world[1], sel), pa.float64()),
            "z": pa.array(np.take(p_world[2], sel), pa.float64()),
            "roll_rate": pa.array(np.take(rates[0], sel), pa.float64()),
            "pitch_rate": pa.array(np.take(rates[1], sel), pa.float64()),
            "scan_t_ns": pa.array(np.take(scans.t_ns, s_sel), pa.int64()),
            "scan_dt_s": pa.array(np.take(scan_dt, s_sel), pa.float64()),
        }
    )


def _beam_directions(
    scans: ScanBatch,
    scan_mount: IntArray,
    mount_list: list[Mount],
    s: IntArray,
    b: IntArray,
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Unit beam directions (D, 3) and origins (D, 3) in base_link for every (scan
    geometry, beam), and each point's row ``key`` (N,) into them. A geometry is a scan's
    (mount, angle_min, angle_increment); a laser keeps one, so D is about its beam count."""
    geometry = np.stack(
        [scan_mount.astype(np.float64), scans.angle_min, scans.angle_increment], axis=1
    )
    unique, scan_geometry = np.unique(geometry, axis=0, return_inverse=True)
    scan_geometry = scan_geometry.reshape(-1)
    lengths = np.bincount(scans.scan, minlength=scans.t_ns.size)
    beams = np.zeros(unique.shape[0], dtype=np.int64)
    np.maximum.at(beams, scan_geometry, lengths)
    offset = np.concatenate([[0], np.cumsum(beams)[:-1]])
    directions = np.zeros((int(beams.sum()), 3))
    origins = np.zeros((int(beams.sum()), 3))
    for g, (code, angle_min, increment) in enumerate(unique):  # per geometry, not per point
        if code < 0:
            continue  # no mount: its points were dropped already
        mount = mount_list[int(code)]
        theta = angle_min + np.arange(beams[g]) * increment
        rows = slice(int(offset[g]), int(offset[g] + beams[g]))
        directions[rows] = np.c_[np.cos(theta), np.sin(theta)] @ mount.rotation[:, :2].T
        origins[rows] = mount.translation_m
    key = np.take(offset, np.take(scan_geometry, s)) + b
    return directions, origins, key


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def run_project(
    workspace: Workspace, log_id: str, config: PipelineConfig, *, overwrite: bool = False
) -> ProjectResult:
    """Project one log's scans into the world (see the module docstring)."""
    return run_on_log(
        workspace,
        log_id,
        lambda log_dir, start: _project_in(
            log_dir, log_id, config, overwrite=overwrite, start=start
        ),
        _log,
    )


def _project_in(
    log_dir: Path, log_id: str, config: PipelineConfig, *, overwrite: bool, start: float
) -> ProjectResult:
    manifest = Manifest(log_dir / Workspace.MANIFEST_NAME)
    laser_path = log_dir / "laser.parquet"
    pose_path = log_dir / "pose.parquet"
    tf_path = log_dir / "tf_static.json"
    if config.topics.lasers == () or not laser_path.is_file():
        raise StageError(
            "projection needs the lasers role, and this log has none (no laser.parquet; "
            "[topics] lasers accepts sensor_msgs/msg/LaserScan topics)",
            path=laser_path,
        )
    if not pose_path.is_file():
        raise StageError("no pose; run `terrain pose` first", path=pose_path)
    inputs = {"laser": file_sha256(laser_path), "pose": file_sha256(pose_path)}
    if tf_path.is_file():
        inputs["tf_static"] = file_sha256(tf_path)
    ingest_files = {"laser.parquet": inputs["laser"]}
    if "tf_static" in inputs:
        ingest_files["tf_static.json"] = inputs["tf_static"]
    require_finished(manifest.stage("ingest"), "ingest", ingest_files, log_dir)
    require_finished(manifest.stage("pose"), "pose", {"pose.parquet": inputs["pose"]}, log_dir)
    cfg_hash = stage_config_hash(config)
    out_path = log_dir / OUTPUT
    record = manifest.stage(STAGE)
    if (
        record is not None
        and not overwrite
        and check_up_to_date(record, inputs=inputs, config_hash=cfg_hash, outputs=[out_path])
    ):
        return ProjectResult(
            log_id,
            "up_to_date",
            int(record.row_counts.get("points", 0)),
            int(record.row_counts.get("scans", 0)),
            {k: int(v) for k, v in record.rejects.items()},
            time.perf_counter() - start,
        )

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
    # The paper's Fig. 4 from the log itself, and on simulated logs the points' z error
    # against the true terrain, accumulated batch by batch as the points are made.
    agreement = ScanAgreement()
    try:
        ground = true_ground(log_dir)
    except StageError as exc:  # a simulated log posed without GPS: no tie to the truth
        ground = None
        warnings.append(f"no z error against the true terrain: {exc}")
    z_error = ZErrorAccumulator() if ground is not None else None
    counts = Counts()
    previous_scan_ns: dict[str, int] = {}
    fig4_until_ns: int | None = None
    batches = iter_table_batches(laser_path, "laser", columns=LASER_COLUMNS, batch_rows=SCAN_BATCH)
    with TableWriter(
        out_path, "points", source_sha256=sha, config_hash=cfg_hash, extra_metadata=frame_meta
    ) as writer:
        while True:
            t = time.perf_counter()
            batch = next(batches, None)
            if batch is None:
                break
            scans = ScanBatch.from_record_batch(batch)
            timings["read"] += time.perf_counter() - t
            t = time.perf_counter()
            table = project_batch(scans, mounts, poses, previous_scan_ns, counts)
            timings["project"] += time.perf_counter() - t
            t = time.perf_counter()
            writer.write(table)
            timings["write"] += time.perf_counter() - t
            t = time.perf_counter()
            if table.num_rows:
                first_ns = int(pc.min(table.column("scan_t_ns")).as_py())
                if fig4_until_ns is None:
                    fig4_until_ns = first_ns + int(FIG4_SECONDS * 1e9)
                if first_ns < fig4_until_ns:
                    agreement.feed(table)
            if ground is not None and z_error is not None and table.num_rows:
                some = table.take(pa.array(np.arange(0, table.num_rows, Z_ERROR_STRIDE)))
                xyz = np.stack([some.column(c).to_numpy() for c in "xyz"], axis=1)
                z_error.feed(some.column("laser"), some.column("range").to_numpy(), ground(xyz))
            timings["figures"] += time.perf_counter() - t
    t = time.perf_counter()
    fig4 = agreement.result()
    figure_files = [p.name for p in write_fig4(fig4, log_dir, log_id)]
    if z_error is not None:
        figure_files += [p.name for p in write_z_error(z_error.result(), log_dir, title=log_id)]
    timings["figures"] += time.perf_counter() - t
    fit = fig4.fit
    manifest.set_header(
        project={
            "fig4": {  # NaN (too few pairs for a line) is written as null
                "slope_m_per_s": _finite_or_none(fit.slope_m_per_s),
                "intercept_m": _finite_or_none(fit.intercept_m),
                "r2": _finite_or_none(fit.r2),
                "pairs": fig4.pairs,
                "flat_points": fig4.flat_points,
                "files": figure_files,
            }
        }
    )
    dropped = {k: v for k, v in counts.rejects.items() if v}
    returns = counts.points + sum(counts.rejects.values())
    if dropped:
        warnings.append(
            f"{sum(dropped.values())} of {returns} returns dropped ("
            + ", ".join(f"{k} {v}" for k, v in dropped.items())
            + ")"
        )
    timings["total"] = time.perf_counter() - start
    manifest.record_stage(
        STAGE,
        StageRecord(
            inputs=inputs,
            config_hash=cfg_hash,
            outputs=(OUTPUT, *figure_files),
            row_counts={"points": counts.points, "scans": counts.scans},
            rejects=dict(counts.rejects),
            timings_s={k: round(v, 6) for k, v in sorted(timings.items())},
            warnings=tuple(warnings),
            output_files=digest_files(log_dir, (OUTPUT, *figure_files)),
        ),
    )
    return ProjectResult(
        log_id,
        "projected",
        counts.points,
        counts.scans,
        dict(counts.rejects),
        time.perf_counter() - start,
        warnings=tuple(warnings),
        points_per_s=counts.points / max(timings["project"], 1e-9),
        fig4=f"Fig. 4 {fit.describe()}",
    )


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _laser_frames(laser_path: Path) -> list[str]:
    """The distinct ``frame_id`` of the scans (read as one small dictionary column)."""
    frames: set[str] = set()
    for batch in iter_table_batches(laser_path, "laser", columns=["frame_id"], batch_rows=65_536):
        frames.update(str(f or "") for f in pc.unique(batch.column("frame_id")).to_pylist())
    return sorted(frames)


__all__ = [
    "STAGE",
    "PoseStream",
    "PoseWindow",
    "ProjectResult",
    "ScanBatch",
    "project_batch",
    "run_project",
    "stage_config_hash",
]

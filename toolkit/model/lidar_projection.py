"""3-D lidar returns -> the paper's points ``L_i`` of eq. (1), each at its own time (Sect. 3).

A 3-D lidar reports each return already as a point in its own frame, at its own time (the
``lidar`` table: :mod:`toolkit.ingestion.lidar`). Placing it is the laser's arithmetic
(:mod:`toolkit.model.projection`) without the beam geometry::

    p_base  = R_base_lidar p_lidar + t_base_lidar              (the mount, by frame_id)
    p_world = p_world_base(tau) + R_world_base(tau) p_base     (the pose at the return's time)

with the pose interpolated at ``tau`` exactly as for a laser's beam
(:meth:`~toolkit.model.projection.PoseWindow.transform`), so a return recorded as a
``LaserScan`` or as a ``PointCloud2`` lands at the same place. The vehicle moves about 2 m
during a 10 Hz sweep at 20 m/s: placing every return with its scan's single pose would smear
the ground by that much, which is why each return keeps its own time.

Each point keeps its lidar (as the laser column), its ring (as the beam), its range, its
scan's stamp and the time since the same lidar's previous scan. Returns are dropped and
counted as the laser's are: ``no_mount`` (a frame no mount places on the vehicle) and
``no_pose`` (no pose at its time).

Arrays only: reading the table and the pose and writing the cloud are the project stage's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.geometry.mounts import Mount
from toolkit.model.projection import POINT_CHUNK, Counts, PoseWindow


@dataclass(frozen=True)
class Returns:
    """A batch of lidar returns, in time order: ``t_ns`` (N,) each return's time,
    ``scan_t_ns`` (N,) its scan's stamp, ``lidar_code`` (N,) and ``frame_code`` (N,) codes
    into ``lidar_names`` and ``frame_names``, ``ring`` (N,) int32 (-1 when the cloud has
    none), ``p_lidar`` (3, N) metres in the lidar's frame."""

    t_ns: IntArray
    scan_t_ns: IntArray
    lidar_code: IntArray
    lidar_names: list[str]
    frame_code: IntArray
    frame_names: list[str]
    ring: NDArray[np.int32]
    p_lidar: FloatArray


@dataclass(frozen=True)
class PreparedReturns:
    """A batch with what its projection needs from the batches before it (each lidar's
    previous scan) and from the pose (the rows its times span): projecting it
    (:func:`project_returns`) is a pure function any thread may run."""

    returns: Returns
    #: Time since the same lidar's previous scan (N,) s, NaN in a lidar's first scan.
    scan_dt: FloatArray
    #: Each frame's mount as an index into ``mount_list``, -1 for none (F,).
    frame_mount: IntArray
    mount_list: tuple[Mount, ...]
    #: Scans that begin in this batch (a scan split between two batches counts once).
    new_scans: int
    window: PoseWindow


@dataclass
class ScanClock:
    """Each lidar's last scan stamp (ns) and the interval before it (s), carried from batch
    to batch, for ``scan_dt_s``: a scan split between two batches is one scan."""

    last_ns: dict[str, int] = field(default_factory=dict)
    last_dt_s: dict[str, float] = field(default_factory=dict)

    def intervals(self, name: str, stamps: IntArray) -> tuple[IntArray, FloatArray, int]:
        """For a lidar's distinct scan stamps ``stamps`` (sorted) in a batch: the stamps
        with the one carried over first, the time since the scan before each (NaN for a
        lidar's first scan), and how many scans begin in this batch."""
        last = self.last_ns.get(name)
        if last is None:
            full = stamps
            first_dt = np.nan
        else:
            full = np.unique(np.concatenate([[last], stamps]))
            first_dt = self.last_dt_s.get(name, np.nan)
        # Differences in integer ns (stamps near 1e18 ns lose 256 ns as float64).
        dt = np.concatenate([[first_dt], np.diff(full) * 1e-9])
        self.last_ns[name], self.last_dt_s[name] = int(full[-1]), float(dt[-1])
        return full, dt, int(full.size - (last is not None))


def prepare_returns(
    returns: Returns,
    mounts: dict[str, Mount],
    clock: ScanClock,
    pose_window: Callable[[int, int], PoseWindow],
) -> PreparedReturns:
    """The sequential part of projecting a batch: ``clock`` carries each lidar's last scan
    from batch to batch, and ``pose_window(t_lo_ns, t_hi_ns)`` gives the pose rows over the
    batch's times."""
    scan_dt = np.full(returns.t_ns.size, np.nan)
    new_scans = 0
    for code, name in enumerate(returns.lidar_names):  # per lidar, not per return
        rows = np.flatnonzero(returns.lidar_code == code)
        if rows.size == 0:
            continue
        full, dt, new = clock.intervals(name, np.unique(returns.scan_t_ns[rows]))
        scan_dt[rows] = dt[np.searchsorted(full, returns.scan_t_ns[rows])]
        new_scans += new
    mount_list = tuple(mounts.values())
    code_of = {m.frame: k for k, m in enumerate(mount_list)}
    frame_mount = np.array([code_of.get(f, -1) for f in returns.frame_names], dtype=np.int64)
    window = (
        pose_window(int(returns.t_ns.min()) - 1, int(returns.t_ns.max()) + 1)
        if returns.t_ns.size
        else PoseWindow.empty()
    )
    return PreparedReturns(returns, scan_dt, frame_mount, mount_list, new_scans, window)


def project_returns(batch: PreparedReturns) -> tuple[list[dict[str, NDArray[Any]]], Counts]:
    """Project a prepared batch: its points as columns, a dict per chunk of
    :data:`~toolkit.model.projection.POINT_CHUNK` returns (``t_ns`` (tau), ``lidar``,
    ``beam`` (the ring), ``range``, ``x``, ``y``, ``z``, ``roll_rate`` (gamma),
    ``pitch_rate`` (psi), ``scan_t_ns``, ``scan_dt_s``), and its counts. A pure function."""
    returns = batch.returns
    counts = Counts(scans=batch.new_scans)
    chunks = [
        _project_chunk(batch, slice(lo, lo + POINT_CHUNK), counts)
        for lo in range(0, returns.t_ns.size, POINT_CHUNK)
    ]
    return chunks, counts


def _project_chunk(batch: PreparedReturns, rows: slice, counts: Counts) -> dict[str, NDArray[Any]]:
    """The points of returns ``rows``, a chunk at a time so temporaries stay in cache."""
    r = batch.returns
    mount = np.take(batch.frame_mount, r.frame_code[rows])
    p = r.p_lidar[:, rows]
    p_base = np.empty_like(p)
    for k, m in enumerate(batch.mount_list):  # per mount, not per return
        on = mount == k
        if on.any():
            p_base[:, on] = m.rotation @ p[:, on] + m.translation_m[:, None]
    t_ns = r.t_ns[rows]
    world, rates, ok = batch.window.transform(t_ns, p_base)
    mounted = mount >= 0
    counts.rejects["no_mount"] += int(np.count_nonzero(~mounted))
    ok &= mounted & np.isfinite(world).all(axis=0)  # never a NaN point written as a good one
    counts.rejects["no_pose"] += int(np.count_nonzero(mounted & ~ok))
    columns: dict[str, NDArray[Any]] = {
        "t_ns": t_ns,
        "lidar": r.lidar_code[rows],
        "beam": r.ring[rows],
        "range": np.sqrt((p * p).sum(axis=0)).astype(np.float32),
        "x": world[0],
        "y": world[1],
        "z": world[2],
        "roll_rate": rates[0],
        "pitch_rate": rates[1],
        "scan_t_ns": r.scan_t_ns[rows],
        "scan_dt_s": batch.scan_dt[rows],
    }
    if not ok.all():
        sel = np.flatnonzero(ok)
        columns = {c: np.take(v, sel) for c, v in columns.items()}
    counts.points += columns["t_ns"].size
    return columns


__all__ = ["PreparedReturns", "Returns", "ScanClock", "prepare_returns", "project_returns"]

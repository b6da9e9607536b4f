"""Laser returns -> the paper's points ``L_i`` of eq. (1) (Sect. 3, projection; Sect. 4).

After projection every return is a point with the six features of the paper's eq. (1)::

    L_i = [x, y, z, tau, gamma, psi]                                                  (1)

its position in the world frame, the time it was observed and the first derivatives of the
vehicle's estimated roll (gamma) and pitch (psi) then. Each return is placed with the pose
*at the beam's own time* and the laser's mount (``base_link_from_laser``, a
:class:`~toolkit.geometry.mounts.Mount`)::

    tau_b     = t_scan + b * time_increment                      (ROS LaserScan: stamp = beam 0)
    theta_b   = angle_min + b * angle_increment
    p_laser   = r_b (cos theta_b, sin theta_b, 0)
    p_world   = p_world_base(tau_b) + R_world_base(tau_b) (R_base_laser p_laser + t_base_laser)

``p_world_base`` and the rates are interpolated linearly between the two pose rows around
``tau_b`` and ``R_world_base`` on the rotation group (:meth:`PoseWindow.transform`: scipy's
:class:`~scipy.spatial.transform.Slerp`, the constant angular velocity arc between the two
attitudes, which per-angle interpolation of roll, pitch and yaw is not; it also never wraps
yaw the long way round). Each point also keeps its scan's time and the time since that
laser's previous scan (``scan_dt_s``, NaN for a laser's first scan).

Returns are dropped and counted by reason (:data:`REJECT_REASONS`, in the order checked):
``bad_scan`` (every return of a scan whose angles or ``time_increment`` are not finite),
``no_return`` (NaN/inf range), ``out_of_range`` (outside the scan's ``[max(range_min, 0),
range_max]``: a negative range is never a return, even under a negative ``range_min``, which
would place it behind the laser), ``no_mount`` (a laser whose frame no mount places on the
vehicle) and ``no_pose`` (before the first or after the last pose row, or inside a gap of the
pose longer than :data:`MAX_POSE_GAP_S`: no estimate to place it with).

Arrays only: reading the scans and the pose, the threads and the writing are the project
stage's (:mod:`toolkit.stages.project`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from toolkit.arrays import FloatArray, IntArray
from toolkit.geometry.mounts import Mount

#: Points projected at a time within a batch: small enough that the ~40 temporary arrays of
#: the arithmetic stay in the processor's cache (32 k points: 256 kB each), large enough that
#: numpy's per-call overhead is small. 32 k ran 3.2x faster than a whole batch at once; 16 k
#: and 8 k slower again (measured, ``PoseWindow.transform``).
POINT_CHUNK = 32_768
#: Longest interval between two pose rows a point may be interpolated across, s. The pose is
#: written at 100 Hz and has holes only where its IMU had gaps (no estimate there).
MAX_POSE_GAP_S = 0.05
#: Reasons a return is dropped, in the order they are checked.
REJECT_REASONS = ("bad_scan", "no_return", "out_of_range", "no_mount", "no_pose")


# --------------------------------------------------------------------------------------
# The pose at each return's time
# --------------------------------------------------------------------------------------


@dataclass
class PoseWindow:
    """Pose rows covering a stretch of time: ``t_ns`` (K,), ``position`` (K, 3) m,
    ``rotation`` (K rotations, world_from_base), ``rates`` (K, 2) roll and pitch rate rad/s."""

    t_ns: IntArray
    position: FloatArray
    rotation: Rotation
    rates: FloatArray

    @classmethod
    def empty(cls) -> PoseWindow:
        """No pose rows: the pose is defined nowhere."""
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), Rotation.identity(0), np.zeros((0, 2)))

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


# --------------------------------------------------------------------------------------
# A batch of scans, made ready to project
# --------------------------------------------------------------------------------------


@dataclass
class Scans:
    """Scans flattened to one row per beam: ``scan`` (M,) index of each beam's scan in the
    batch, ``beam`` (M,), ``range_m`` (M,) float32, plus the per-scan arrays (S,)."""

    t_ns: IntArray
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


@dataclass(frozen=True)
class PreparedBatch:
    """A batch of scans with everything its projection needs from the scans before it (the
    time since each laser's previous scan) and from the pose (the pose rows it spans), so
    projecting it (:func:`project_points`) is a pure function any thread may run."""

    scans: Scans
    #: Time since the same laser's previous scan (S,) s, NaN for a laser's first scan.
    scan_dt: FloatArray
    #: Each scan's mount (S,) as an index into ``mount_list``, -1 for none.
    scan_mount: IntArray
    mount_list: tuple[Mount, ...]
    #: False (S,) for a scan whose angles or timing are not finite.
    good_scan: NDArray[np.bool_]
    window: PoseWindow


def prepare_scans(
    scans: Scans,
    mounts: dict[str, Mount],
    previous_scan_ns: dict[str, int],
    pose_window: Callable[[int, int], PoseWindow],
) -> PreparedBatch:
    """The sequential part of projecting a batch, in scan order: ``previous_scan_ns`` (laser
    -> stamp of its last scan) is carried from batch to batch for ``scan_dt_s``, and
    ``pose_window(t_lo_ns, t_hi_ns)`` gives the pose rows over the batch's beam times."""
    scan_dt = scan_intervals(scans, previous_scan_ns)
    mount_list = tuple(mounts.values())
    code_of = {m.frame: k for k, m in enumerate(mount_list)}
    frame_mount = np.array([code_of.get(f, -1) for f in scans.frame_names], dtype=np.int64)
    good_scan = (
        np.isfinite(scans.angle_min)
        & np.isfinite(scans.angle_increment)
        & np.isfinite(scans.time_increment)
    )
    span = beam_time_span(scans, good_scan)
    window = pose_window(*span) if span is not None else PoseWindow.empty()
    return PreparedBatch(
        scans, scan_dt, frame_mount[scans.frame_code], mount_list, good_scan, window
    )


def scan_intervals(scans: Scans, previous_scan_ns: dict[str, int]) -> FloatArray:
    """Time since the same laser's previous scan (S,) s, NaN for a laser's first scan; each
    laser's last stamp is left in ``previous_scan_ns`` for the next batch."""
    scan_dt = np.full(scans.t_ns.size, np.nan)
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
    return scan_dt


def beam_time_span(scans: Scans, good_scan: NDArray[np.bool_]) -> tuple[int, int] | None:
    """The times ``(t_lo_ns, t_hi_ns)`` the batch's beams span, from its scans' first and
    last beam times, a nanosecond beyond either end (the beams' offsets are rounded, the span
    is not); None for a batch without a beam."""
    n_scans = scans.t_ns.size
    if not (n_scans and scans.range_m.size):
        return None
    lengths = np.bincount(scans.scan, minlength=n_scans)
    span_ns = np.where(good_scan, (lengths - 1).clip(0) * scans.time_increment * 1e9, 0.0)
    t_lo = int((scans.t_ns + np.minimum(span_ns, 0.0).astype(np.int64)).min()) - 1
    t_hi = int((scans.t_ns + np.maximum(span_ns, 0.0).astype(np.int64)).max()) + 1
    return t_lo, t_hi


# --------------------------------------------------------------------------------------
# Projection of a prepared batch
# --------------------------------------------------------------------------------------


def project_points(batch: PreparedBatch) -> tuple[list[dict[str, NDArray[Any]]], Counts]:
    """Project a prepared batch: its points as columns, a dict per chunk of
    :data:`POINT_CHUNK` beams (``t_ns`` (tau), ``x``, ``y``, ``z``, ``roll_rate`` (gamma),
    ``pitch_rate`` (psi), and ``scan``, ``beam``, ``range``, ``scan_t_ns``, ``scan_dt_s``),
    and its counts. A pure function: safe to run for several batches at once in threads,
    numpy releasing the GIL in its loops."""
    scans = batch.scans
    counts = Counts(scans=scans.t_ns.size)
    if scans.range_m.size == 0:
        return [], counts
    directions, origins, offset, scan_geometry = beam_directions(
        scans, batch.scan_mount, batch.mount_list
    )
    scan_key = np.take(offset, scan_geometry)
    chunks = [
        _project_chunk(batch, slice(lo, lo + POINT_CHUNK), directions, origins, scan_key, counts)
        for lo in range(0, scans.range_m.size, POINT_CHUNK)
    ]
    return chunks, counts


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
    s, b, r = _placeable_returns(batch, rows, counts)
    r = r.astype(np.float64)

    # Beam times: stamp + beam x time_increment (ROS LaserScan: the stamp is beam 0's time).
    offset_ns = np.round(b * np.take(scans.time_increment, s) * 1e9).astype(np.int64)
    t_ns = np.take(scans.t_ns, s) + offset_ns
    # Beam directions and origins in base_link, per scan geometry and beam (see
    # beam_directions), gathered per point.
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


def _placeable_returns(
    batch: PreparedBatch, rows: slice, counts: Counts
) -> tuple[IntArray, IntArray, NDArray[np.float32]]:
    """The scan, beam and range of the flattened beams ``rows`` that a mounted laser
    returned from within its range, in a good scan; the others counted in ``counts`` by
    reason (all but ``no_pose``, which placing them finds)."""
    scans = batch.scans
    s, b, r = scans.scan[rows], scans.beam[rows], scans.range_m[rows]
    usable = np.take(batch.good_scan, s)
    finite = np.isfinite(r)
    counts.rejects["bad_scan"] += int(r.size - np.count_nonzero(usable))
    counts.rejects["no_return"] += int(np.count_nonzero(usable & ~finite))
    finite &= usable
    # Never below 0, whatever the scan's range_min claims (a negative r points backwards).
    lowest = np.maximum(np.take(scans.range_min, s), 0.0)
    with np.errstate(invalid="ignore"):
        in_range = finite & (r >= lowest) & (r <= np.take(scans.range_max, s))
    counts.rejects["out_of_range"] += int(np.count_nonzero(finite & ~in_range))
    mounted = in_range & (np.take(batch.scan_mount, s) >= 0)
    counts.rejects["no_mount"] += int(np.count_nonzero(in_range & ~mounted))
    if not mounted.all():  # (gathers are the costliest step here: skipped when all stay)
        keep = np.flatnonzero(mounted)
        s, b, r = np.take(s, keep), np.take(b, keep), np.take(r, keep)
    return s, b, r


def beam_directions(
    scans: Scans,
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


__all__ = [
    "MAX_POSE_GAP_S",
    "POINT_CHUNK",
    "REJECT_REASONS",
    "Counts",
    "PoseWindow",
    "PreparedBatch",
    "Scans",
    "beam_directions",
    "beam_time_span",
    "prepare_scans",
    "project_points",
    "scan_intervals",
]

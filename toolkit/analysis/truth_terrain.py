"""How far projected points lie from the true ground, for simulated logs.

A simulated log carries what it was made from: the ``terrain_sim`` metadata record (in the
log directory's ``mcap_metadata.json``) holds the world's parameters (``world``, WorldParams as
JSON), its ``seed`` and the simulator frame's geodetic ``origin``;
:func:`toolkit.sim.world.make_world` rebuilds that world bit for bit. The height error of a
point is then its z minus the true terrain height under it::

    p_sim      = move_between_frames(p, pose_origin, sim_origin)           (exact)
    (s, d)     = route.to_route(p_sim.x, p_sim.y, s_guess)        (route coordinates)
    z_error    = p_sim.z - terrain.height(s, d)

``pose_origin`` is the pose frame's origin (the pose table's ``enu_origin`` metadata, the
log's agreeing GPS fix); ``s_guess`` the nearest route sample, 0.5 m apart, from a k-d tree,
from which three Newton steps of ``to_route`` reach millimetres. Points beyond the terrain the
simulator models (farther than its coarse grid's half width from the centreline, or off the
ends of the route) have no true height: their error is NaN.

This is the one place outside the command line that imports :mod:`toolkit.sim`: the ground
truth a simulated log was made from lives only there.

:class:`ZErrorAccumulator` streams the errors into statistics by laser and by range bin:
count, mean, RMS, median, median and 90th percentile of ``|error|``; the quantiles from a
fixed histogram (``resolution_m`` bins within ``+-limit_m``, one open bin each side), so
memory is fixed however many points pass. :func:`write_z_error` writes them as CSV and PNG.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from toolkit.analysis.figures import new_figure, save_png_atomic, write_csv_atomic
from toolkit.analysis.histograms import bins_covering, histogram_quantile
from toolkit.arrays import FloatArray, IntArray
from toolkit.errors import ConfigError, StageError, ToolkitError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import move_between_frames
from toolkit.layout import LogFiles
from toolkit.sim.record import SIM_RECORD, sim_origin
from toolkit.tableio import iter_table_batches, read_table, read_table_metadata

#: Spacing of the route samples the first guess of a point's route position comes from, m.
ROUTE_GUESS_SPACING_M = 0.5
#: Columns of points.parquet the streaming driver reads.
COLUMNS = ("laser", "range", "x", "y", "z")
BATCH_ROWS = 1_048_576
CSV_NAME = "z_error_by_laser_and_range.csv"
PNG_NAME = "z_error_by_laser_and_range.png"
#: ``laser`` of the rows over every laser.
ALL_LASERS = "all"
#: Terrain tiles one height query spans at most (:meth:`TrueGround.terrain_height_m`): the
#: simulator's window over them is a few MB, where all of an hour's route is gigabytes.
TILES_PER_QUERY = 8


class TrueGround:
    """The z error of pose-frame points against the simulator's terrain: call with
    ``xyz_m`` (N, 3) in the pose frame, get ``z_error_m`` (N,) (NaN off the modelled
    terrain). Build with :func:`true_ground`."""

    def __init__(self, world: Any, sim_origin: GeodeticOrigin, pose_origin: GeodeticOrigin):
        self.world = world
        self.sim_origin = sim_origin
        self.pose_origin = pose_origin
        route = world.route
        self._s_grid = np.arange(0.0, route.length_m, ROUTE_GUESS_SPACING_M)
        cx, cy, _ = route.sample(self._s_grid)
        self._tree = cKDTree(np.c_[cx, cy])
        self._max_d_m = float(world.terrain.coarse_half_width_m)

    def to_sim(self, xyz_m: ArrayLike) -> FloatArray:
        """Pose-frame points (N, 3) -> the simulator's frame (N, 3), through geodetic: both
        are maps of the curved Earth (:mod:`toolkit.geometry.map_frame`) about origins a
        GPS error apart, which tangent planes would tilt against each other by that
        distance over the Earth's radius (10 m: 0.16 m of height 100 km away)."""
        p = np.asarray(xyz_m, np.float64).reshape(-1, 3)
        moved, _ = move_between_frames(p, None, self.pose_origin, self.sim_origin)
        return moved

    def route_coordinates(self, xyz_m: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Pose-frame points (N, 3) -> their route coordinates ``s``, ``d`` (N,) and their
        height (N,) in the simulator's frame. Touches no terrain tile: ~1 us a point
        (measured: 0.6 s for 650 k) and safe from any thread (it only reads the route and its
        k-d tree, whose caches this object's constructor has filled)."""
        xs = self.to_sim(xyz_m)
        if xs.shape[0] == 0:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        _, j = self._tree.query(xs[:, :2])
        s, d = self.world.route.to_route(xs[:, 0], xs[:, 1], self._s_grid[j])
        return s, d, xs[:, 2]

    def terrain_height_m(self, s_m: FloatArray, d_m: FloatArray) -> FloatArray:
        """True terrain height (N,) at route coordinates (N,), NaN where not modelled.

        Builds the terrain tiles the points lie on (a tile of the simulator's terrain costs
        ~55 ms to synthesise after its neighbour, ~115 ms alone: measured), and they are
        cached in the world, which is not thread-safe: one caller at a time. The points are
        looked up :data:`TILES_PER_QUERY` tiles at a time: the simulator's query joins every
        tile from the lowest ``s`` asked to the highest into one grid, which for a whole
        hour's route would be gigabytes. The heights are the same either way (each comes
        from the grid cells around its point, to rounding: the grid's origin moves)."""
        s = np.asarray(s_m, np.float64)
        d = np.asarray(d_m, np.float64)
        h = np.full(s.shape, np.nan)
        with np.errstate(invalid="ignore"):
            on = np.isfinite(s) & np.isfinite(d) & (np.abs(d) <= self._max_d_m)
            on &= (s >= 0.0) & (s <= self.world.route.length_m)
        rows = np.flatnonzero(on)
        if rows.size == 0:
            return h
        span_m = TILES_PER_QUERY * float(self.world.terrain.tile_length_m)
        stretch = np.floor(s[rows] / span_m).astype(np.int64)
        order = np.argsort(stretch, kind="stable")
        rows, stretch = rows[order], stretch[order]
        starts = np.flatnonzero(np.r_[True, stretch[1:] != stretch[:-1]])
        for lo, hi in zip(starts, np.r_[starts[1:], rows.size], strict=True):
            at = rows[lo:hi]
            h[at] = self.world.terrain.height(s[at], d[at])
        return h

    def checked_stretch(self, s_m: FloatArray, every: int) -> IntArray:
        """The index of the checked stretch of road (N,) each route position lies on, -1 for
        none: the terrain's tiles ``k`` with ``k % every == 0``, less their last two coarse
        grid steps (a height there interpolates towards the next tile, which would then be
        built too; see :meth:`toolkit.sim.terrain.Terrain.window`). A sample of stretches of
        road costs one tile each however many points land on it, where a sample of points
        from everywhere costs every tile they touch."""
        terrain = self.world.terrain
        length = float(terrain.tile_length_m)
        s = np.asarray(s_m, np.float64)
        with np.errstate(invalid="ignore"):  # NaN or inf s: on no stretch
            tile = np.floor(s / length)
            inside = (s - tile * length) < length - 2.0 * float(terrain.coarse_spacing_m) - 1e-6
            inside &= (s >= 0.0) & (s <= self.world.route.length_m)
        return np.where(inside & (tile % every == 0), tile, -1).astype(np.int64)

    def stretch_every(self, fewest: int, most_every: int) -> int:
        """How many tiles apart the checked stretches are (:meth:`checked_stretch`):
        ``most_every``, or fewer on a route too short to give ``fewest`` stretches that
        far apart (down to every tile)."""
        tiles = int(np.ceil(self.world.route.length_m / float(self.world.terrain.tile_length_m)))
        return int(min(most_every, max(1, tiles // max(1, fewest))))

    def height_m(self, xyz_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """True terrain height (N,) under pose-frame points (N, 3) and the points' own
        height (N,), both in the simulator's frame; the terrain NaN where not modelled."""
        s, d, z = self.route_coordinates(xyz_m)
        if s.size == 0:
            return np.zeros(0), np.zeros(0)
        return self.terrain_height_m(s, d), z

    def __call__(self, xyz_m: ArrayLike) -> FloatArray:
        """``z_error_m`` (N,): point height minus true terrain height, m."""
        h, z = self.height_m(xyz_m)
        return z - h


def true_ground(log_dir: Path) -> TrueGround | None:
    """The :class:`TrueGround` of a simulated log's directory (a workspace's
    ``logs/<id>/``), or None for a log that is not simulated (no ``terrain_sim`` record).

    StageError when the log is simulated but its truth cannot be rebuilt: the record is
    malformed, or the pose table is missing or has no geodetic ``enu_origin`` (a log posed
    without GPS is in a frame of its own, which the simulator's cannot be mapped onto).
    """
    from toolkit.sim.world import make_world
    from toolkit.sim.world_params import WorldParams

    log_dir = Path(log_dir)
    meta_path = LogFiles(log_dir).mcap_metadata
    if not meta_path.is_file():
        return None
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as exc:
        raise StageError(f"unreadable log metadata: {exc}", path=meta_path) from exc
    sim = meta.get(SIM_RECORD) if isinstance(meta, dict) else None
    if sim is None:
        return None
    origin_sim = sim_origin(meta)
    try:
        params: dict[str, Any] = {
            k: tuple(_tuples(v)) if isinstance(v, list) else v
            for k, v in json.loads(sim["world"]).items()
        }
        world = make_world(WorldParams(**params), int(sim["seed"]))
    except (KeyError, TypeError, ValueError, ToolkitError) as exc:
        raise StageError(
            f"record {SIM_RECORD!r}: cannot rebuild the simulated world: {exc}", path=meta_path
        ) from exc
    if origin_sim is None:
        raise StageError(f"record {SIM_RECORD!r} has no readable origin", path=meta_path)
    pose_path = LogFiles(log_dir).pose
    if not pose_path.is_file():
        raise StageError("no pose; run `terrain pose` first", path=pose_path)
    origin_text = read_table_metadata(pose_path).get("enu_origin")
    if origin_text is None:
        raise StageError(
            "the pose frame has no geodetic origin (posed without GPS), so the simulator's "
            "terrain cannot be placed in it",
            path=pose_path,
        )
    try:
        pose_origin = GeodeticOrigin(**json.loads(origin_text))
    except (TypeError, ValueError) as exc:
        raise StageError(f"unreadable enu_origin {origin_text!r}", path=pose_path) from exc
    return TrueGround(world, origin_sim, pose_origin)


def where_beams_hit(log_dir: Path, xyz_m: ArrayLike, t_ns: ArrayLike) -> FloatArray:
    """Where the beams of pose-frame points truly hit (N, 3), NaN where either pose is
    undefined: each point ``p`` (N, 3), seen at ``t_ns`` (N,), moved from the estimated pose
    to the true one at its time::

        p_true = T_true(t) T_est(t)^-1 p

    A point is placed with the estimated pose (``pose.parquet``): it lies off the spot its
    beam hit by the pose's error then, horizontally 0.16 m at the median and 0.30 m at
    the 90th percentile on 20-mile simulated races (measured on seeds 801 and 802). The true
    heights *under a point* are therefore the truth 16 cm beside the rock the laser saw; the
    truth *where its beam hit* is what a perfect sensor on the same beam would have
    measured. What remains is the range noise and the mounts' flex, which the truth pose
    does not hold. Both poses are interpolated as the projection interpolates (position
    linearly, attitude by slerp); ``truth_pose.parquet`` shares the pose's frame
    (:mod:`toolkit.stages.truth`). StageError when either table is missing.
    """
    from scipy.spatial.transform import Rotation, Slerp

    from toolkit.geometry.rotations import euler_to_rot

    p = np.asarray(xyz_m, np.float64).reshape(-1, 3)
    t = np.asarray(t_ns, np.int64)
    out = np.full(p.shape, np.nan)
    poses = []
    for name in ("pose", "truth_pose"):
        path = Path(log_dir) / f"{name}.parquet"
        if not path.is_file():
            raise StageError(f"no {name} table to place the truth with", path=path)
        table = read_table(path, name, columns=("t_ns", "x", "y", "z", "roll", "pitch", "yaw"))
        c = {k: table.column(k).to_numpy() for k in table.column_names}
        rpy = np.stack([c["roll"], c["pitch"], c["yaw"]], axis=1).astype(np.float64)
        poses.append((c["t_ns"].astype(np.int64), np.c_[c["x"], c["y"], c["z"]], rpy))
    defined = np.ones(t.size, bool)
    for pose_t, _, _ in poses:
        defined &= (t >= pose_t[0]) & (t <= pose_t[-1]) if pose_t.size >= 2 else False
    rows = np.flatnonzero(defined)
    if rows.size == 0:
        return out
    # Times as seconds from the first point: float64 keeps nanoseconds there.
    t0 = int(t[rows].min())
    at_s = (t[rows] - t0) * 1e-9

    def pose_at(pose_t: IntArray, pos: FloatArray, rpy: FloatArray) -> tuple[Rotation, FloatArray]:
        s = (pose_t - t0) * 1e-9
        rotation = Slerp(s, Rotation.from_matrix(euler_to_rot(rpy)))(at_s)
        position = np.stack([np.interp(at_s, s, pos[:, k]) for k in range(3)], axis=1)
        return rotation, position

    est_rotation, est_position = pose_at(*poses[0])
    true_rotation, true_position = pose_at(*poses[1])
    base = est_rotation.inv().apply(p[rows] - est_position)
    out[rows] = true_rotation.apply(base) + true_position
    return out


def _tuples(v: list[Any]) -> list[Any]:
    """JSON lists nested in a list -> tuples (WorldParams' fixed_features are tuples)."""
    return [tuple(_tuples(x)) if isinstance(x, list) else x for x in v]


# --------------------------------------------------------------------------------------
# Statistics of the error by laser and range
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ZErrorConfig:
    """Range bins of ``range_bin_m`` up to ``max_range_m`` (farther points in the last
    bin); error histogram of ``resolution_m`` bins within ``+-limit_m``."""

    range_bin_m: float = 5.0
    max_range_m: float = 80.0
    resolution_m: float = 0.001
    limit_m: float = 1.0

    def __post_init__(self) -> None:
        for name in ("range_bin_m", "max_range_m", "resolution_m", "limit_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"z error statistics: {name} must be positive, got {value!r}")

    @property
    def n_range_bins(self) -> int:
        return bins_covering(self.max_range_m, self.range_bin_m)

    @property
    def half_bins(self) -> int:
        """Histogram bins on each side of zero, within the limit."""
        return bins_covering(self.limit_m, self.resolution_m)


@dataclass(frozen=True)
class ZErrorRow:
    """Error statistics of one laser (or :data:`ALL_LASERS`) over one range bin
    (``range_hi_m`` inf for the row over all ranges, and for the last bin)."""

    laser: str
    range_lo_m: float
    range_hi_m: float
    count: int
    mean_m: float
    rms_m: float
    median_m: float
    median_abs_m: float
    p90_abs_m: float


@dataclass(frozen=True)
class ZErrorResult:
    """Rows per laser: first over all ranges, then per non-empty range bin; then the same
    over all lasers. ``off_terrain``: points with no true height (not in the rows)."""

    config: ZErrorConfig
    rows: tuple[ZErrorRow, ...]
    points: int
    off_terrain: int
    seconds: float

    def overall(self, laser: str = ALL_LASERS) -> ZErrorRow:
        """The row of ``laser`` over all ranges."""
        for row in self.rows:
            if row.laser == laser and row.range_lo_m == 0.0 and math.isinf(row.range_hi_m):
                return row
        raise KeyError(laser)

    @property
    def lasers(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.laser for r in self.rows if r.laser != ALL_LASERS))


class ZErrorAccumulator:
    """Streaming z-error statistics by laser and range bin: :meth:`feed`, then
    :meth:`result`. Memory: per laser, one histogram per range bin (16 x 2002 int64 with the
    defaults, 256 kB)."""

    def __init__(self, config: ZErrorConfig | None = None) -> None:
        self.config = config or ZErrorConfig()
        self._hist: dict[str, NDArray[np.int64]] = {}
        self._sums: dict[str, FloatArray] = {}  # (3, R): count, sum e, sum e^2
        self.points = 0
        self.off_terrain = 0
        self._seconds = 0.0

    def feed(
        self,
        laser: ArrayLike | pa.Array | pa.ChunkedArray,
        range_m: ArrayLike,
        z_error_m: ArrayLike,
    ) -> None:
        """Add points: laser names (N,), range (N,) m, z error (N,) m (NaN: off terrain)."""
        start = time.perf_counter()
        c = self.config
        if isinstance(laser, pa.Array | pa.ChunkedArray):
            laser = laser.to_numpy(zero_copy_only=False)
        names_all = np.asarray(laser).astype(str)
        r = np.asarray(range_m, np.float64)
        e = np.asarray(z_error_m, np.float64)
        if not (names_all.shape == r.shape == e.shape) or e.ndim != 1:
            raise StageError(
                "z error statistics: laser, range and error must be 1-D arrays of one length, "
                f"got shapes {names_all.shape}, {r.shape}, {e.shape}"
            )
        self.points += e.size
        ok = np.isfinite(e)
        self.off_terrain += int((~ok).sum())
        names_all, r, e = names_all[ok], r[ok], e[ok]
        rb = np.clip(np.floor(r / c.range_bin_m), 0, c.n_range_bins - 1).astype(np.int64)
        h = c.half_bins
        # Bin 0: below -limit; 1..2h: [(-h + k - 1) res, (-h + k) res); 2h + 1: >= limit.
        eb = np.clip(np.floor(e / c.resolution_m) + h + 1, 0, 2 * h + 1).astype(np.int64)
        n_e = 2 * h + 2
        names, inverse = np.unique(names_all, return_inverse=True)
        inverse = inverse.ravel()
        for k, name in enumerate(names):  # per laser, not per point
            sel = inverse == k
            if name not in self._hist:
                self._hist[name] = np.zeros((c.n_range_bins, n_e), np.int64)
                self._sums[name] = np.zeros((3, c.n_range_bins))
            rs, es = rb[sel], e[sel]
            self._hist[name].ravel()[:] += np.bincount(
                rs * n_e + eb[sel], minlength=self._hist[name].size
            )
            s = self._sums[name]
            s[0] += np.bincount(rs, minlength=c.n_range_bins)
            s[1] += np.bincount(rs, weights=es, minlength=c.n_range_bins)
            s[2] += np.bincount(rs, weights=es * es, minlength=c.n_range_bins)
        self._seconds += time.perf_counter() - start

    def result(self) -> ZErrorResult:
        c = self.config
        rows: list[ZErrorRow] = []
        lasers = sorted(self._hist)
        groups: list[tuple[str, NDArray[np.int64], FloatArray]] = [
            (n, self._hist[n], self._sums[n]) for n in lasers
        ]
        if lasers:
            groups.append(
                (
                    ALL_LASERS,
                    np.sum([self._hist[n] for n in lasers], axis=0),
                    np.sum([self._sums[n] for n in lasers], axis=0),
                )
            )
        for name, hist, sums in groups:
            rows.append(self._row(name, 0.0, math.inf, hist.sum(axis=0), sums.sum(axis=1)))
            for b in np.flatnonzero(sums[0]):
                lo = float(b * c.range_bin_m)
                hi = math.inf if b == c.n_range_bins - 1 else float((b + 1) * c.range_bin_m)
                rows.append(self._row(name, lo, hi, hist[b], sums[:, b]))
        return ZErrorResult(c, tuple(rows), self.points, self.off_terrain, self._seconds)

    def _row(
        self, laser: str, lo: float, hi: float, hist: NDArray[np.int64], sums: FloatArray
    ) -> ZErrorRow:
        c = self.config
        n = int(hist.sum())
        h = c.half_bins
        # |e| histogram: bins [k res, (k + 1) res) for k < h, then everything beyond.
        folded = hist[h + 1 : 2 * h + 1] + hist[h:0:-1]
        folded = np.append(folded, hist[0] + hist[2 * h + 1])
        mean = sums[1] / n if n else math.nan
        return ZErrorRow(
            laser=laser,
            range_lo_m=lo,
            range_hi_m=hi,
            count=n,
            mean_m=float(mean),
            rms_m=float(math.sqrt(sums[2] / n)) if n else math.nan,
            median_m=histogram_quantile(hist, 0.5, -(h + 1) * c.resolution_m, c.resolution_m),
            median_abs_m=histogram_quantile(folded, 0.5, 0.0, c.resolution_m, open_low=False),
            p90_abs_m=histogram_quantile(folded, 0.9, 0.0, c.resolution_m, open_low=False),
        )


# --------------------------------------------------------------------------------------
# A log, and the outputs
# --------------------------------------------------------------------------------------


def z_error_of(
    log_dir: Path,
    points_path: Path | None = None,
    config: ZErrorConfig | None = None,
    *,
    batch_rows: int = BATCH_ROWS,
) -> ZErrorResult | None:
    """The z-error statistics of a simulated log's projected points (``points_path``,
    default ``log_dir/points.parquet``), streamed; None when the log is not simulated."""
    ground = true_ground(log_dir)
    if ground is None:
        return None
    path = Path(points_path) if points_path is not None else LogFiles(Path(log_dir)).points
    acc = ZErrorAccumulator(config)
    for batch in iter_table_batches(path, "points", columns=COLUMNS, batch_rows=batch_rows):
        xyz = np.stack([batch.column(c).to_numpy() for c in "xyz"], axis=1)
        acc.feed(batch.column("laser"), batch.column("range").to_numpy(), ground(xyz))
    return acc.result()


CSV_HEADER = (
    "laser",
    "range_lo_m",
    "range_hi_m",
    "count",
    "mean_m",
    "rms_m",
    "median_m",
    "median_abs_m",
    "p90_abs_m",
)


def write_z_error(result: ZErrorResult, out_dir: Path, title: str = "") -> tuple[Path, Path]:
    """Write :data:`CSV_NAME` (one row per :class:`ZErrorRow`) and :data:`PNG_NAME` (median
    and 90th percentile of ``|z error|`` against range, one colour per laser) into
    ``out_dir``, atomically. Returns the two paths."""
    out_dir = Path(out_dir)
    rows = [tuple(getattr(r, f) for f in CSV_HEADER) for r in result.rows]
    csv_path = write_csv_atomic(out_dir / CSV_NAME, CSV_HEADER, rows)

    fig = new_figure()
    ax = fig.add_subplot(1, 1, 1)
    step = result.config.range_bin_m
    by_laser: Mapping[str, list[ZErrorRow]] = {
        name: [r for r in result.rows if r.laser == name and not _is_overall(r)]
        for name in result.lasers
    }
    colours = [f"C{k % 10}" for k in range(len(by_laser))]
    for colour, (name, mine) in zip(colours, by_laser.items(), strict=True):
        x = np.array([r.range_lo_m + step / 2 for r in mine])
        ax.plot(x, [r.median_abs_m for r in mine], "o-", ms=3, color=colour, label=f"{name} median")
        ax.plot(
            x, [r.p90_abs_m for r in mine], "--", lw=0.8, color=colour, label=f"{name} 90th pct"
        )
    ax.set_xlabel(f"range ({step:g} m bins, centres) (m)")
    ax.set_ylabel("|z error| against the true terrain (m)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3)
    ax.legend(loc="upper left", fontsize=6, ncol=2)
    overall = [r for r in result.rows if r.laser == ALL_LASERS and _is_overall(r)]
    summary = (
        f"all lasers: median |e| {overall[0].median_abs_m * 1000:.1f} mm, "
        f"p90 {overall[0].p90_abs_m * 1000:.1f} mm, {overall[0].count} points"
        if overall
        else "no points"
    )
    ax.set_title(
        f"{title + ': ' if title else ''}point height error by range\n{summary}", fontsize=9
    )
    fig.tight_layout()
    png_path = save_png_atomic(fig, out_dir / PNG_NAME)
    return csv_path, png_path


def _is_overall(row: ZErrorRow) -> bool:
    return row.range_lo_m == 0.0 and math.isinf(row.range_hi_m)


__all__ = [
    "ALL_LASERS",
    "CSV_HEADER",
    "CSV_NAME",
    "PNG_NAME",
    "TrueGround",
    "ZErrorAccumulator",
    "ZErrorConfig",
    "ZErrorResult",
    "ZErrorRow",
    "true_ground",
    "where_beams_hit",
    "write_z_error",
    "z_error_of",
]

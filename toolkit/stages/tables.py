"""Tables stage: every log's events and points -> the training and test tables (paper sect. 7).

For each event (a stretch of the rear-axle path, ``events.parquet``) and each rear tyre, the
laser points observed *before* the rear axle reached the stretch that lie within
``[model] wheel_window_radius_m`` (30 cm, sect. 7: "all laser points fall within 30cm of
terrain the vehicle's rear tires traversed") of the ground that tyre traversed in it. Those
are the points the model of sect. 4 scores for that tyre (``tables/event_points.parquet``,
the paper's ``L_i = [x, y, z, tau, gamma, psi]`` with ``tau`` the point's time in seconds).

The tyres' paths: base_link is on the ground below the rear-axle centre, so the tyres touch
the ground at ``(0, +-track_m / 2, 0)`` in base_link; their world (x, y) follow from the pose
(position and yaw; the roll of the body moves the contact patch by millimetres, neglected).
Each tyre's path over an event is sampled at most ``PATH_STEP_M`` apart
(:mod:`toolkit.tyre_paths`; the pose rows, densified), and a point is near it when a sample
lies within the radius: a point exactly at the radius from the polyline is then within
``sqrt(r^2 + (step/2)^2) - r`` (1 mm) of being missed, a known, negligible bias. A point
may serve several events (near the end of one stretch and the start of the next) and is then
listed under each.

"Before": the point's time is earlier than the event's start, and by at most
``[tables] max_lookahead_s`` (a point seen minutes earlier, on a loop of the course, is not
"the terrain ahead"). Events with fewer than ``[tables] min_points_per_wheel`` points under a
tyre cannot be scored; they are dropped and counted (``too_few_points``).

Split (sect. 7 trains on miles 60-70 and tests on 70-80): by distance along the driven path.
``split_scope = "all_logs"``: the logs in time order are one route; the first
``train_fraction`` of its total length trains, the rest tests. ``"per_log"``: each log is
split the same way on its own. An event belongs to the side its middle lies on.

Streaming: points are read a batch at a time in time order; only the events whose start lies
within ``max_lookahead_s`` after the batch have their tyre paths sampled and indexed (a
KD-tree of their samples, rebuilt per batch), from the pose rows around them (the pose is
read forward a batch at a time, :class:`~toolkit.timewindow.TimeWindow`, its yaw unwrapped
as over the whole log, :class:`RunningUnwrap`). The points, the pose and the tyre paths are
never whole in memory; each log's events are (a dozen numbers an event, ~4 MB for an
hour's 28,000). Both tables are written aside and published when both are complete; a kill
between the two renames leaves outputs the manifest does not match, which the next run
redoes.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict, deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from toolkit.config import ModelConfig, PipelineConfig, TablesConfig, VehicleConfig
from toolkit.errors import StageError
from toolkit.layout import LogFiles, log_file_name
from toolkit.manifest import (
    Manifest,
    file_sha256,
    require_finished,
)
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.tableio import (
    TableWriter,
    iter_table_batches,
    read_table,
    read_table_metadata,
    table_num_rows,
)
from toolkit.timewindow import Columns, TimeWindow
from toolkit.tyre_paths import (
    META_KEPT_WITHIN_M,
    PATH_STEP_M,
    TyrePaths,
    near_cells,
    tyre_paths,
)
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

STAGE = "tables"
#: What the tables are made from: the split, the vehicle (tyre track) and, of the model's
#: settings, the radius around a tyre's track alone (the patches' sampling and size are
#: learn's and evaluate's business: changing them leaves the tables as they are).
CONFIG_SECTIONS = ("tables", "vehicle", "model.wheel_window_radius_m")
#: Points per read batch.
POINT_BATCH = 262_144
#: Pose rows per read batch (the pose is streamed; 65,536 rows are 11 minutes at 100 Hz).
POSE_BATCH = 65_536
#: Threads matching batches at once (the machine's two cores).
WORKERS = 2
#: How far before a batch's latest point a later batch's points may still lie, ns: the
#: points are in scan order, and a scan's beams may reach back by its duration (a negative
#: time_increment; Stanley's lasers scan in 13 ms). A second is far beyond that.
FINAL_MARGIN_NS = 1_000_000_000
WHEELS = ("left", "right")
#: Samples asked for per point near a tyre path (at 5 cm spacing a 30 cm radius holds ~13
#: of one event's path; a point near two events' ends, or a slow stretch, holds more).
NEIGHBOURS = 24
POINT_COLUMNS = ("t_ns", "laser", "x", "y", "z", "roll_rate", "pitch_rate")
EVENT_COLUMNS = (
    "event_id",
    "t_start_ns",
    "t_end_ns",
    "s_start_m",
    "s_end_m",
    "speed_mph",
    "shock_g",
    "ruggedness",
    "rough",
)


@dataclass(frozen=True)
class SplitTotals:
    """What one split holds (the numbers sect. 7 reports)."""

    events: int
    positives: int
    points: int


@dataclass(frozen=True)
class TablesResult:
    """What :func:`run_tables` did."""

    status: str  # "written" or "up_to_date"
    logs: int
    splits: dict[str, SplitTotals]
    rejects: dict[str, int]
    seconds: float
    warnings: tuple[str, ...] = ()
    #: Distinct laser points under any tyre (``points`` per split counts rows: a point under
    #: two events is two rows). Counted before unscorable events are dropped.
    distinct_points: int = 0

    def summary(self) -> str:
        """The totals per split, as sect. 7 reports them."""
        parts = [
            f"{name}: {t.events} events ({t.positives} rough, "
            f"{100.0 * t.positives / max(t.events, 1):.2f} %), {t.points} point rows"
            for name, t in self.splits.items()
        ]
        if self.distinct_points:
            parts.append(f"{self.distinct_points} distinct points")
        dropped = {k: v for k, v in self.rejects.items() if v}
        if dropped:
            parts.append("dropped " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
        return f"tables {self.status.replace('_', ' ')} from {self.logs} log(s): " + "; ".join(
            parts
        )


# --------------------------------------------------------------------------------------
# Tyre paths
# --------------------------------------------------------------------------------------


class EventPaths(Protocol):
    """Whatever samples the tyre paths of a run of a log's events (:class:`PathSource`)."""

    def paths(self, first: int, stop: int) -> TyrePaths: ...


@dataclass(frozen=True)
class PathSource:
    """Pose rows and a log's events, from which the tyre paths of any run of consecutive
    events the rows cover are sampled when needed (:meth:`paths`), so a log's paths are
    never whole in memory.

    ``pose_yaw`` is unwrapped as over the whole log (:class:`RunningUnwrap`, the stage's
    pose stream): its steps are within pi, so :func:`tyre_paths` unwrapping a slice of it
    leaves it as it is, and the paths of a run of events are bit for bit those
    :func:`tyre_paths` gives over the whole log (but where rounding puts an unwrapped step
    a hair past pi, which the second unwrap would move by 2 pi). The rows may be a
    window of the log's pose (the stage passes the rows around the open events), the
    events are the log's."""

    pose_t_ns: IntArray
    pose_xy: FloatArray
    pose_yaw: FloatArray
    t_start_ns: IntArray
    t_end_ns: IntArray
    track_m: float

    def paths(self, first: int, stop: int) -> TyrePaths:
        """The paths of events ``first .. stop - 1`` (their ``event`` the log's event rows),
        from the pose rows around them (the row at or before the first start to the row at
        or after the last end: what the interpolation reads)."""
        t = self.pose_t_ns
        lo = max(int(np.searchsorted(t, self.t_start_ns[first], side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t, self.t_end_ns[stop - 1], side="left")) + 1, t.size)
        run = tyre_paths(
            t[lo:hi],
            self.pose_xy[lo:hi],
            self.pose_yaw[lo:hi],
            self.t_start_ns[first:stop],
            self.t_end_ns[first:stop],
            self.track_m,
        )
        return TyrePaths(run.xy, run.event + first, run.wheel, run.first)


class RunningUnwrap:
    """``np.unwrap`` of a table's ``yaw`` column read batch by batch (a
    :data:`~toolkit.timewindow.BatchTransform`): bit for bit the unwrap of the whole column.

    ``np.unwrap`` (period 2 pi) adds to each sample the running sum of the corrections its
    steps need, ``c_k = ((d_k + pi) mod 2 pi) - pi - d_k`` for a step ``d_k`` of at least
    pi (0 otherwise; a step of exactly +pi stays +pi). It has no way to go on from an
    earlier call, so the step into each batch and the running sum are carried here and
    summed in the same order (``np.cumsum`` with the carried sum prepended): a test checks
    the result against ``np.unwrap`` over the whole column for random splits."""

    def __init__(self, column: str = "yaw") -> None:
        self.column = column
        self._last_raw: float | None = None
        self._correction: float | None = None

    def __call__(self, cols: Columns) -> Columns:
        p = np.asarray(cols[self.column], np.float64)
        if p.size == 0:
            return cols
        first = self._last_raw is None
        dd = np.diff(p) if first else np.diff(np.concatenate([[self._last_raw], p]))
        # np.unwrap's own steps, for a float array and its default period 2 pi.
        ddmod = np.mod(dd + np.pi, 2 * np.pi) - np.pi
        np.copyto(ddmod, np.pi, where=(ddmod == -np.pi) & (dd > 0))
        ph_correct = ddmod - dd
        np.copyto(ph_correct, 0, where=np.abs(dd) < np.pi)
        up = np.array(p, copy=True)
        if first:
            running = ph_correct.cumsum()
            up[1:] = p[1:] + running
        else:
            running = np.concatenate([[self._correction], ph_correct]).cumsum()[1:]
            up = p + running
        if running.size:
            self._correction = float(running[-1])
        elif self._correction is None:  # a first batch of one row: nothing to carry yet
            self._correction = 0.0
        self._last_raw = float(p[-1])
        return {**cols, self.column: up}


# --------------------------------------------------------------------------------------
# Points under the tyres, one log
# --------------------------------------------------------------------------------------


@dataclass
class LogInputs:
    """One log's inputs and their hashes."""

    log_id: str
    log_dir: Path
    hashes: dict[str, str]
    first_t_ns: int = 0


def _match_batch(
    batch: pa.RecordBatch,
    events_t_start: IntArray,
    source: EventPaths,
    radius_m: float,
    lookahead_ns: int,
) -> tuple[IntArray, IntArray, IntArray]:
    """Matches of one batch of points: (point row, event row, wheel) (each (Q,)).

    Two sieves, cheapest first: a coarse grid of the cells the open events' tyre paths
    pass within the radius of (:func:`~toolkit.tyre_paths.near_cells`; ~90 % of the cloud
    is off the tyre tracks), then every sample within the radius (KD-tree), asked as the
    :data:`NEIGHBOURS` nearest (a point with that many within the radius is asked again
    with no limit)."""
    t = batch.column("t_ns").to_numpy()
    empty = (np.zeros(0, np.int64),) * 3
    if t.size == 0:
        return empty
    t_lo, t_hi = int(t.min()), int(t.max())
    open_events = np.flatnonzero((events_t_start > t_lo) & (events_t_start <= t_hi + lookahead_ns))
    if open_events.size == 0:
        return empty
    # Events are in time order: the open ones are a run, and only their paths are sampled.
    paths = source.paths(int(open_events[0]), int(open_events[-1]) + 1)
    if paths.event.size == 0:
        return empty
    sample_xy, sample_event, sample_wheel = paths.xy, paths.event, paths.wheel
    x, y = batch.column("x").to_numpy(), batch.column("y").to_numpy()
    # Sieve 1: grid cells of side r; a point within r of a sample lies in the sample's cell
    # or one of its 8 neighbours.
    candidate = near_cells(sample_xy, x, y, radius_m)
    if candidate.size == 0:
        return empty
    # Sieve 2: every sample within the radius (KD-tree), asked as the NEIGHBOURS nearest,
    # vectorised (~65 % of the candidates have one; asking them all at once is faster than
    # first asking each for its nearest, measured); the rare point whose last neighbour is
    # still inside (a slow stretch: samples 1-2 cm apart) is asked for all of them.
    tree = cKDTree(sample_xy)
    xy = np.c_[np.take(x, candidate), np.take(y, candidate)]
    dist, idx = tree.query(xy, k=NEIGHBOURS, distance_upper_bound=radius_m)
    near_rows = np.flatnonzero(np.isfinite(dist[:, 0]))
    if near_rows.size == 0:
        return empty
    near, xy, dist, idx = candidate[near_rows], xy[near_rows], dist[near_rows], idx[near_rows]
    inside = np.isfinite(dist)
    point = np.repeat(near, inside.sum(axis=1))
    samples = idx[inside]
    full = np.flatnonzero(inside[:, -1])
    if full.size:
        hits = tree.query_ball_point(xy[full], r=radius_m)
        lengths = np.array([len(h) for h in hits], dtype=np.int64)  # per saturated point
        extra = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])
        keep = ~np.isin(point, near[full])
        point = np.concatenate([point[keep], np.repeat(near[full], lengths)])
        samples = np.concatenate([samples[keep], extra])
    # One row per (point, event, wheel), as one int64 key; only points seen before the
    # event, and not too long before.
    n_ev = np.int64(events_t_start.size)
    key = np.unique(
        (point.astype(np.int64) * n_ev + sample_event[samples]) * 2 + sample_wheel[samples]
    )
    wheel = key % 2
    event = (key // 2) % n_ev
    point = key // 2 // n_ev
    ahead = events_t_start[event] - t[point]
    ok = (ahead > 0) & (ahead <= lookahead_ns)
    return point[ok], event[ok], wheel[ok]


@dataclass(frozen=True)
class MatchedBatch:
    """The event-point rows matched from one batch of points."""

    table: pa.Table
    #: Each row's event, as a row index into the log's events (rows of ``table``,).
    event_row: IntArray
    #: Rows per (event row, wheel) in this batch (E, 2).
    counts: NDArray[np.int64]
    #: Distinct points among the rows (a point under two events is one point, two rows).
    distinct: int
    #: The latest point time of the batch, ns.
    t_hi_ns: int


def _require_points_near_enough(points_path: Path, radius_m: float, log_id: str) -> None:
    """StageError when the cloud keeps only points nearer the tyres' paths than the tables
    reach (``[project] keep = "near_path"`` under another radius): the events would be
    scored on a strip narrower than they ask, quietly."""
    text = read_table_metadata(points_path).get(META_KEPT_WITHIN_M)
    if text is None:
        return
    try:
        kept = float(text)
    except ValueError:
        raise StageError(
            f"{log_id}: metadata {META_KEPT_WITHIN_M} = {text!r} is not a distance; run "
            f"`terrain project --overwrite --log {log_id}` again",
            path=points_path,
        ) from None
    if kept < radius_m + PATH_STEP_M:
        raise StageError(
            f"{log_id}: its points were kept only within {kept:g} m of the tyres' "
            f"paths, and the tables reach {radius_m:g} m (+ {PATH_STEP_M:g} m of path "
            f"sampling); run `terrain project --overwrite --log {log_id}` again",
            path=points_path,
        )


def _event_points_of_log(inputs: LogInputs, config: TablesSettings) -> Iterator[MatchedBatch]:
    """The event-point rows of one log, batch by batch, in the order of the points."""
    log_dir = inputs.log_dir
    events = read_table(LogFiles(log_dir).events, "events", columns=list(EVENT_COLUMNS))
    t_start = events.column("t_start_ns").to_numpy().astype(np.int64)
    t_end = events.column("t_end_ns").to_numpy().astype(np.int64)
    event_id = events.column("event_id").to_numpy().astype(np.int64)
    pose_path = LogFiles(log_dir).pose
    if table_num_rows(pose_path, "pose") < 2 or t_start.size == 0:
        return
    # The pose is streamed: each batch of points gets the rows around its open events.
    poses = TimeWindow(
        pose_path,
        "pose",
        columns=("t_ns", "x", "y", "yaw"),
        batch_rows=POSE_BATCH,
        transform=RunningUnwrap("yaw"),
    )
    radius = config.model.wheel_window_radius_m
    _require_points_near_enough(LogFiles(log_dir).points, radius, inputs.log_id)
    lookahead_ns = int(config.tables.max_lookahead_s * 1e9)
    wheel_names = pa.array(list(WHEELS))

    latest_lo = int(np.iinfo(np.int64).min) + FINAL_MARGIN_NS  # the latest batch start yet

    def source_for(batch: pa.RecordBatch) -> PathSource | None:
        """The pose rows the batch's open events need (see :func:`_match_batch`), read
        here, in the order of the batches; those further back than any later batch can
        reach (points are in time order to within :data:`FINAL_MARGIN_NS`) let go."""
        nonlocal latest_lo
        t = batch.column("t_ns").to_numpy()
        if t.size == 0:
            return None
        t_lo, t_hi = int(t.min()), int(t.max())
        if t_lo < latest_lo - FINAL_MARGIN_NS:  # the rows it needs may be let go
            raise StageError(
                f"points are not in time order (a batch reaches back "
                f"{(latest_lo - t_lo) * 1e-9:.3f} s); run `terrain project --overwrite` "
                f"on {inputs.log_id}",
                path=LogFiles(log_dir).points,
            )
        latest_lo = max(latest_lo, t_lo)
        open_events = np.flatnonzero((t_start > t_lo) & (t_start <= t_hi + lookahead_ns))
        poses.forget_before(latest_lo - FINAL_MARGIN_NS)
        if open_events.size == 0:
            return None
        rows = poses.rows(int(t_start[open_events[0]]), int(t_end[open_events[-1]]))
        return PathSource(
            rows["t_ns"],
            np.c_[rows["x"], rows["y"]],
            rows["yaw"],
            t_start,
            t_end,
            config.vehicle.track_m,
        )

    def rows_of(batch: pa.RecordBatch, source: PathSource | None) -> MatchedBatch:
        point, event, wheel = (
            _match_batch(batch, t_start, source, radius, lookahead_ns)
            if source is not None
            else (np.zeros(0, np.int64),) * 3
        )
        counts = np.zeros((t_start.size, 2), dtype=np.int64)
        np.add.at(counts, (event, wheel), 1)
        t_all = batch.column("t_ns").to_numpy()
        t_hi = int(t_all.max()) if t_all.size else 0
        if point.size == 0:
            return MatchedBatch(pa.table({}), event, counts, 0, t_hi)
        take = pa.array(point)
        t_ns = t_all[point]
        table = pa.table(
            {
                "log_id": pa.array([inputs.log_id] * point.size, pa.string()),
                "event_id": pa.array(event_id[event], pa.int64()),
                "wheel": pc.take(wheel_names, pa.array(wheel)),
                "x": pc.take(batch.column("x"), take),
                "y": pc.take(batch.column("y"), take),
                "z": pc.take(batch.column("z"), take),
                "tau": pa.array(t_ns * 1e-9, pa.float64()),
                "roll_rate": pc.take(batch.column("roll_rate"), take),
                "pitch_rate": pc.take(batch.column("pitch_rate"), take),
                "laser": pc.take(batch.column("laser"), take).cast(pa.string()),
                "t_ns": pa.array(t_ns, pa.int64()),
            }
        )
        return MatchedBatch(table, event, counts, int(np.unique(point).size), t_hi)

    # Batches are matched by a pool of threads (the KD-tree's queries and numpy's loops run
    # outside the GIL) and handed back in order, so the output is the same as matching one
    # batch after another; at most WORKERS + 1 batches are in flight.
    pending: deque[Future[MatchedBatch]] = deque()
    batches = iter_table_batches(
        LogFiles(log_dir).points,
        "points",
        columns=POINT_COLUMNS,
        batch_rows=POINT_BATCH,
        as_dictionary=["laser"],
    )
    with ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="tables") as pool:
        try:
            for batch in batches:
                pending.append(pool.submit(rows_of, batch, source_for(batch)))
                if len(pending) > WORKERS:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:  # an error, or the consumer stopped: run nothing on
                future.cancel()


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def _log_inputs(workspace: Workspace) -> tuple[list[LogInputs], list[str]]:
    """The logs that have finished events, points and pose (in time order), and a warning
    for each log left out and why."""
    usable: list[LogInputs] = []
    warnings: list[str] = []
    made_by = {need.name: need.made_by for need in SPEC.needs}
    for log_id in workspace.log_ids():
        files = workspace.log(log_id)
        log_dir = files.dir
        manifest = Manifest(files.manifest)
        missing = [
            stage
            for name, stage in made_by.items()
            if manifest.stage(stage) is None or not files.path(name).is_file()
        ]
        if missing:
            warnings.append(
                f"{log_id}: left out (no finished {', '.join(missing)}; run `terrain "
                f"{missing[0]}` on it)"
            )
            continue
        hashes = {name: file_sha256(files.path(name)) for name in made_by}
        for name, stage in made_by.items():
            require_finished(
                manifest.stage(stage), stage, {log_file_name(name): hashes[name]}, log_dir
            )
        # Events and points must both come from the pose there is now: tyre paths from one
        # pose matched against points placed with another would be quietly wrong.
        for stage in ("label", "project"):
            record = manifest.stage(stage)
            if record is not None and record.inputs.get("pose") != hashes["pose"]:
                raise StageError(
                    f"{log_id}: its {stage} was made from an earlier pose; run `terrain "
                    f"{stage} -w {workspace.root} --log {log_id}` again",
                    path=LogFiles(log_dir).pose,
                )
        # The pose is in time order: its first row is its first time (read alone).
        head = next(
            iter_table_batches(LogFiles(log_dir).pose, "pose", columns=["t_ns"], batch_rows=1),
            None,
        )
        first = int(head.column(0)[0].as_py()) if head is not None and head.num_rows else 0
        usable.append(LogInputs(log_id, log_dir, hashes, first))
    usable.sort(key=lambda li: (li.first_t_ns, li.log_id))
    return usable, warnings


def _splits(events_by_log: list[pa.Table], config: TablesSettings) -> list[NDArray[np.str_]]:
    """'train' / 'test' per event of each log (see the module docstring)."""
    frac = config.tables.train_fraction
    lengths = [
        float(pc.max(e.column("s_end_m")).as_py() or 0.0) if e.num_rows else 0.0
        for e in events_by_log
    ]
    out = []
    offset = 0.0
    total = sum(lengths)
    for events, length in zip(events_by_log, lengths, strict=True):
        mid = 0.5 * (events.column("s_start_m").to_numpy() + events.column("s_end_m").to_numpy())
        if config.tables.split_scope == "per_log":
            train = mid < frac * length
        else:
            train = offset + mid < frac * total
        out.append(np.where(train, "train", "test"))
        offset += length
    return out


@dataclass(frozen=True)
class TablesSettings:
    """What tables reads of the configuration: its section, the vehicle (track, wheelbase)
    and the model (the radius of a tyre's patch)."""

    tables: TablesConfig
    vehicle: VehicleConfig
    model: ModelConfig


def run_tables(
    workspace: Workspace, config: PipelineConfig, *, overwrite: bool = False
) -> TablesResult:
    """Build ``tables/events.parquet`` and ``tables/event_points.parquet`` from every log
    (see the module docstring)."""
    return cast(TablesResult, run_stage(SPEC, workspace, config, overwrite=overwrite))


def _gather(
    workspace: Workspace, config: PipelineConfig
) -> tuple[dict[str, str], tuple[list[LogInputs], list[str]]]:
    """Every usable log's events, points and pose, hashed (``<log id>/<name>``), and the
    logs with the warnings on those left out."""
    del config  # which logs are usable does not depend on it
    logs, warnings = _log_inputs(workspace)
    if not logs:
        raise StageError(
            "no log has finished events, points and pose; run `terrain label` and "
            "`terrain project` first",
            path=workspace.logs_dir,
        )
    inputs = {f"{li.log_id}/{n}": h for li in logs for n, h in sorted(li.hashes.items())}
    return inputs, (logs, warnings)


def _recall(last: Recalled) -> TablesResult:
    """The outcome of up-to-date tables, from their record."""
    record = last.record
    splits = {
        k.removesuffix("_events"): SplitTotals(
            int(record.row_counts.get(f"{k}", 0)),
            int(record.row_counts.get(k.replace("_events", "_positives"), 0)),
            int(record.row_counts.get(k.replace("_events", "_points"), 0)),
        )
        for k in ("train_events", "test_events")
    }
    return TablesResult(
        "up_to_date",
        len({key.split("/")[0] for key in record.inputs}),
        splits,
        dict(record.rejects),
        last.seconds,
        distinct_points=int(record.row_counts.get("distinct_points", 0)),
    )


def _compute(call: Call) -> Made:
    """Write the two tables (the module docstring); the runner records them."""
    config: TablesSettings = call.settings
    workspace, cfg_hash, start = call.workspace, call.config_hash, call.start
    logs, warnings = call.found
    outputs = [workspace.events_table, workspace.event_points_table]
    events_by_log = [
        read_table(LogFiles(li.log_dir).events, "events", columns=list(EVENT_COLUMNS))
        for li in logs
    ]
    split_of = _splits(events_by_log, config)
    # One pass: the matches streamed into the event-points table, counting per tyre. An
    # event with fewer than min_points_per_wheel points under a tyre cannot be scored and is
    # left out of both tables; whether it has enough is known once the points have passed
    # its start (only points seen before it count), so each batch's rows wait in `held`
    # until every event in them is final, then go out filtered. The wait is bounded by
    # max_lookahead_s of rows.
    counts_by_log: list[NDArray[np.int64]] = []
    distinct_points = 0
    sources = [li.hashes["events"] for li in logs]
    points_writer = TableWriter(
        workspace.event_points_table, "event_points", source_sha256=sources, config_hash=cfg_hash
    )
    events_writer = TableWriter(
        workspace.events_table, "tables_events", source_sha256=sources, config_hash=cfg_hash
    )
    min_points = config.tables.min_points_per_wheel
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    try:
        for li, events in zip(logs, events_by_log, strict=True):
            counts = np.zeros((events.num_rows, 2), dtype=np.int64)
            t_start = events.column("t_start_ns").to_numpy().astype(np.int64)
            held: deque[MatchedBatch] = deque()

            def release(matched: MatchedBatch, counts: NDArray[np.int64] = counts) -> None:
                scored = counts.min(axis=1) >= min_points
                keep = np.take(scored, matched.event_row)
                points_writer.write(
                    matched.table if keep.all() else matched.table.filter(pa.array(keep))
                )

            for matched in _event_points_of_log(li, config):
                counts += matched.counts
                distinct_points += matched.distinct
                if matched.table.num_rows:
                    held.append(matched)
                # Points come in time order (to within a scan: FINAL_MARGIN_NS): every point
                # seen before an event starting this long before the batch's last one is in.
                final_ns = matched.t_hi_ns - FINAL_MARGIN_NS
                while held and int(t_start[held[0].event_row].max()) <= final_ns:
                    release(held.popleft())
            while held:
                release(held.popleft())
            counts_by_log.append(counts)
        points_writer.finish()
        timings["match"] = time.perf_counter() - t0
        keep_by_log = [
            c.min(axis=1) >= min_points if c.size else np.zeros(0, bool) for c in counts_by_log
        ]
        rejected = int(sum((~k).sum() for k in keep_by_log))
        points_per_split: dict[str, int] = defaultdict(int)
        positives: dict[str, int] = defaultdict(int)
        n_events: dict[str, int] = defaultdict(int)
        for li, events, split, keep, counts in zip(
            logs, events_by_log, split_of, keep_by_log, counts_by_log, strict=True
        ):
            kept = events.filter(pa.array(keep))
            split_kept = split[keep]
            table = pa.table(
                {
                    "log_id": pa.array([li.log_id] * kept.num_rows, pa.string()),
                    "event_id": kept.column("event_id"),
                    "split": pa.array(split_kept.tolist(), pa.string()),
                    **{c: kept.column(c) for c in EVENT_COLUMNS if c != "event_id"},
                    "points_left": pa.array(counts[keep, 0], pa.int64()),
                    "points_right": pa.array(counts[keep, 1], pa.int64()),
                }
            )
            events_writer.write(table)
            rough = kept.column("rough").to_numpy(zero_copy_only=False)
            for name in ("train", "test"):
                mine = split_kept == name
                n_events[name] += int(mine.sum())
                positives[name] += int(rough[mine].sum())
                points_per_split[name] += int(counts[keep][mine].sum())
        events_writer.finish()
        points_writer.publish()
        events_writer.publish()
    except BaseException:
        points_writer.abort()
        events_writer.abort()
        raise
    splits = {
        name: SplitTotals(n_events[name], positives[name], points_per_split[name])
        for name in ("train", "test")
    }
    rejects = {"too_few_points": rejected}
    if rejected:
        warnings.append(
            f"{rejected} events dropped: fewer than {config.tables.min_points_per_wheel} "
            "points under a tyre"
        )
    row_counts: dict[str, int] = {}
    for name, t in splits.items():
        row_counts[f"{name}_events"] = t.events
        row_counts[f"{name}_positives"] = t.positives
        row_counts[f"{name}_points"] = t.points
    row_counts["distinct_points"] = distinct_points
    if splits["train"].events + splits["test"].events == 0:
        warnings.append("no event to tabulate: the tables are empty (see `terrain label`)")
    outcome = TablesResult(
        "written",
        len(logs),
        splits,
        rejects,
        time.perf_counter() - start,
        tuple(warnings),
        distinct_points=distinct_points,
    )
    return Made(
        outcome,
        tuple(str(p.relative_to(workspace.root)) for p in outputs),
        row_counts=row_counts,
        rejects=rejects,
        timings_s={**timings, "total": time.perf_counter() - start},
        warnings=tuple(warnings),
    )


SPEC = Stage(
    STAGE,
    "workspace",
    needs=(Need("events", "label"), Need("points", "project"), Need("pose", "pose")),
    makes=("events_table", "event_points_table"),
    sections=CONFIG_SECTIONS,
    settings=TablesSettings,
    gather=_gather,
    compute=_compute,
    recall=_recall,
    rows=("train_events", "test_events", "train_points", "test_points"),
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "STAGE",
    "PathSource",
    "RunningUnwrap",
    "SplitTotals",
    "TablesResult",
    "TyrePaths",
    "run_tables",
    "tyre_paths",
]

"""The tables stage's points under the tyres, one log at a time (the stage:
:mod:`toolkit.stages.tables`; the matching itself: :mod:`toolkit.model.tyre_match`).

Points are read a batch at a time in time order; only the events whose start lies within
``max_lookahead_s`` after the batch have their tyre paths sampled and indexed, from the pose
rows around them (the pose is read forward a batch at a time,
:class:`~toolkit.timewindow.TimeWindow`, its yaw unwrapped as over the whole log,
:class:`RunningUnwrap`). Batches are matched by a pool of :data:`WORKERS` threads and handed
back in order. The points, the pose and the tyre paths are never whole in memory.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit.arrays import IntArray
from toolkit.errors import StageError
from toolkit.layout import LogFiles
from toolkit.model.tyre_match import EventPaths, PathSource, match_points
from toolkit.tableio import iter_table_batches, read_table, read_table_metadata, table_num_rows
from toolkit.timewindow import Columns, TimeWindow
from toolkit.tyre_paths import PathsDrawnFrom, cut_differences

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
    """Matches of one batch of points: (point row, event row, wheel) (each (Q,))
    (:func:`~toolkit.model.tyre_match.match_points`)."""
    t = batch.column("t_ns").to_numpy()
    x, y = batch.column("x").to_numpy(), batch.column("y").to_numpy()
    return match_points(t, x, y, events_t_start, source, radius_m, lookahead_ns)


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


def require_cut_fits(
    points_path: Path, log_id: str, drawn_from: PathsDrawnFrom, reach_m: float, workspace: Path
) -> None:
    """StageError, in one line naming the file, what differs and how to redo the cut, when
    the cloud keeps only the points near the tyres' paths (``[project] keep = "near_path"``)
    and these are not the paths the tables draw (from ``drawn_from``) out to ``reach_m``
    (:func:`~toolkit.tyre_paths.cut_differences`): the events would be scored on a strip
    narrower than they ask, or beside their tyres, quietly."""
    differences = cut_differences(read_table_metadata(points_path), drawn_from, reach_m)
    if differences:
        raise StageError(
            f"{log_id}: its points were kept only near the tyres' paths, cut for other "
            f"tables than these ({'; '.join(differences)}); run `terrain project -w "
            f"{workspace} --log {log_id} --overwrite` again",
            path=points_path,
        )


@dataclass(frozen=True)
class _LogEvents:
    """A log's events as arrays (E,): start and end times (ns) and their ids."""

    t_start: IntArray
    t_end: IntArray
    event_id: IntArray


class _PoseFeed:
    """The pose rows each batch of points' open events need (see :func:`_match_batch`),
    read in the order of the batches; rows further back than any later batch can reach
    (points are in time order to within :data:`FINAL_MARGIN_NS`) are let go."""

    def __init__(
        self, inputs: LogInputs, events: _LogEvents, lookahead_ns: int, track_m: float
    ) -> None:
        self.inputs, self.events = inputs, events
        self.lookahead_ns, self.track_m = lookahead_ns, track_m
        self.poses = TimeWindow(
            LogFiles(inputs.log_dir).pose,
            "pose",
            columns=("t_ns", "x", "y", "yaw"),
            batch_rows=POSE_BATCH,
            transform=RunningUnwrap("yaw"),
        )
        self.latest_lo = int(np.iinfo(np.int64).min) + FINAL_MARGIN_NS  # latest batch start

    def source_for(self, batch: pa.RecordBatch) -> PathSource | None:
        """The path source of the batch's open events, or None with none."""
        t = batch.column("t_ns").to_numpy()
        if t.size == 0:
            return None
        t_lo, t_hi = int(t.min()), int(t.max())
        if t_lo < self.latest_lo - FINAL_MARGIN_NS:  # the rows it needs may be let go
            raise StageError(
                f"points are not in time order (a batch reaches back "
                f"{(self.latest_lo - t_lo) * 1e-9:.3f} s); run `terrain project --overwrite` "
                f"on {self.inputs.log_id}",
                path=LogFiles(self.inputs.log_dir).points,
            )
        self.latest_lo = max(self.latest_lo, t_lo)
        t_start, t_end = self.events.t_start, self.events.t_end
        open_events = np.flatnonzero((t_start > t_lo) & (t_start <= t_hi + self.lookahead_ns))
        self.poses.forget_before(self.latest_lo - FINAL_MARGIN_NS)
        if open_events.size == 0:
            return None
        rows = self.poses.rows(int(t_start[open_events[0]]), int(t_end[open_events[-1]]))
        return PathSource(
            rows["t_ns"],
            np.c_[rows["x"], rows["y"]],
            rows["yaw"],
            t_start,
            t_end,
            self.track_m,
        )


def _rows_of(
    batch: pa.RecordBatch,
    source: PathSource | None,
    log_id: str,
    events: _LogEvents,
    radius_m: float,
    lookahead_ns: int,
) -> MatchedBatch:
    """The event-point rows of one batch of points."""
    t_start = events.t_start
    point, event, wheel = (
        _match_batch(batch, t_start, source, radius_m, lookahead_ns)
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
            "log_id": pa.array([log_id] * point.size, pa.string()),
            "event_id": pa.array(events.event_id[event], pa.int64()),
            "wheel": pc.take(pa.array(list(WHEELS)), pa.array(wheel)),
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


def event_points_of_log(
    inputs: LogInputs, radius_m: float, max_lookahead_s: float, track_m: float
) -> Iterator[MatchedBatch]:
    """The event-point rows of one log, batch by batch, in the order of the points: those
    within ``radius_m`` of a rear tyre's path over an event, seen before it by at most
    ``max_lookahead_s`` (tyres ``track_m`` apart)."""
    log_dir = inputs.log_dir
    table = read_table(LogFiles(log_dir).events, "events", columns=list(EVENT_COLUMNS))
    events = _LogEvents(
        table.column("t_start_ns").to_numpy().astype(np.int64),
        table.column("t_end_ns").to_numpy().astype(np.int64),
        table.column("event_id").to_numpy().astype(np.int64),
    )
    if table_num_rows(LogFiles(log_dir).pose, "pose") < 2 or events.t_start.size == 0:
        return
    # The pose is streamed: each batch of points gets the rows around its open events.
    lookahead_ns = int(max_lookahead_s * 1e9)
    feed = _PoseFeed(inputs, events, lookahead_ns, track_m)
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
    args = (inputs.log_id, events, radius_m, lookahead_ns)
    with ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="tables") as pool:
        try:
            for batch in batches:
                pending.append(pool.submit(_rows_of, batch, feed.source_for(batch), *args))
                if len(pending) > WORKERS:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:  # an error, or the consumer stopped: run nothing on
                future.cancel()


__all__ = [
    "EVENT_COLUMNS",
    "FINAL_MARGIN_NS",
    "LogInputs",
    "MatchedBatch",
    "RunningUnwrap",
    "event_points_of_log",
    "require_cut_fits",
]

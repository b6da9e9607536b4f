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

Streaming (:mod:`toolkit.stages.tables_points`; the matching:
:mod:`toolkit.model.tyre_match`): points are read a batch at a time in time order; only the
events whose start lies within ``max_lookahead_s`` after the batch have their tyre paths
sampled and indexed (a KD-tree of their samples, rebuilt per batch), from the pose rows
around them (the pose is read forward a batch at a time,
:class:`~toolkit.timewindow.TimeWindow`, its yaw unwrapped as over the whole log,
:class:`RunningUnwrap`). The points, the pose and the tyre paths are never whole in memory;
each log's events are (a dozen numbers an event, ~4 MB for an hour's 28,000). Both tables
are written aside and published when both are complete; a kill between the two renames
leaves outputs the manifest does not match, which the next run redoes.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict, deque
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit.config import ModelConfig, PipelineConfig, TablesConfig, VehicleConfig
from toolkit.errors import StageError
from toolkit.layout import LogFiles
from toolkit.manifest import (
    Manifest,
)
from toolkit.model.tyre_match import PathSource
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import hash_inputs, remedy, require_inputs_current
from toolkit.stages.tables_points import (
    EVENT_COLUMNS,
    FINAL_MARGIN_NS,
    LogInputs,
    MatchedBatch,
    RunningUnwrap,
    event_points_of_log,
    require_cut_fits,
)
from toolkit.tableio import TableWriter, iter_table_batches, read_table
from toolkit.tyre_paths import PathsDrawnFrom, TyrePaths, tyre_paths
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)


STAGE = "tables"
#: What the tables are made from: the split, the vehicle (tyre track) and, of the model's
#: settings, the radius around a tyre's track alone (the patches' sampling and size are
#: learn's and evaluate's business: changing them leaves the tables as they are).
CONFIG_SECTIONS = ("tables", "vehicle", "model.wheel_window_radius_m")


@dataclass(frozen=True)
class SplitTotals:
    """What one split holds (the numbers sect. 7 reports): its events, the rough ones
    among them (the positives) and the point rows under their tyres. The export's card and
    metadata state the same numbers (:meth:`toolkit.publish.dataset.DatasetFacts.counts`)."""

    events: int
    rough: int
    points: int


@dataclass(frozen=True)
class TablesResult:
    """What the tables stage did."""

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
            f"{name}: {t.events} events ({t.rough} rough, "
            f"{100.0 * t.rough / max(t.events, 1):.2f} %), {t.points} point rows"
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


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def _log_inputs(workspace: Workspace, config: PipelineConfig) -> tuple[list[LogInputs], list[str]]:
    """The logs that have finished events, points and pose (in time order), and a warning
    for each log left out and why. WorkspaceError when a log's events, points or pose are
    not current (:func:`~toolkit.stages.runner.check_needs`: another configuration, other
    code, events or points from another pose than its own); StageError when its points were
    cut near other tyre paths than ``config``
    draws (:func:`~toolkit.stages.tables_points.require_cut_fits`): refused before any
    up-to-date check, so tables made from such a cloud are never current."""
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
                f"{log_id}: left out (no finished {', '.join(missing)}; "
                f"{remedy(missing[0], files, config)})"
            )
            continue
        hashes = hash_inputs(SPEC.needs, files.path)
        # A cloud cut for other tyre paths is said as such (what to widen), before the
        # general staleness of its configuration.
        require_cut_fits(
            files.points,
            log_id,
            PathsDrawnFrom.of(config, hashes),
            config.model.wheel_window_radius_m,
            workspace.root,
        )
        # Each file as its maker last wrote it, with this configuration and code, and
        # events and points both from the pose there is now: tyre paths from one pose
        # matched against points placed with another would be quietly wrong.
        require_inputs_current(SPEC.needs, hashes, files.path, manifest, config, STAGE)
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


def _gather(
    workspace: Workspace, config: PipelineConfig
) -> tuple[dict[str, str], tuple[list[LogInputs], list[str]]]:
    """Every usable log's events, points and pose, hashed (``<log id>/<name>``), and the
    logs with the warnings on those left out."""
    logs, warnings = _log_inputs(workspace, config)
    if not logs:
        # What each log lacks and how it would get it, or why it cannot (the first three).
        why = "; ".join(warnings[:3]) + ("; ..." if len(warnings) > 3 else "")
        raise StageError(
            f"no log has finished events, points and pose: {why or 'the workspace has none'}",
            path=workspace.logs_dir,
        )
    inputs = {f"{li.log_id}/{n}": h for li in logs for n, h in sorted(li.hashes.items())}
    return inputs, (logs, warnings)


def _recall(last: Recalled[TablesSettings]) -> TablesResult:
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


def _match_log(
    li: LogInputs,
    events: pa.Table,
    config: TablesSettings,
    points_writer: TableWriter,
) -> tuple[NDArray[np.int64], int]:
    """Stream one log's matches into the event-points table: its counts per (event, tyre)
    (E, 2) and its distinct points.

    An event with fewer than min_points_per_wheel points under a tyre cannot be scored and
    is left out of both tables; whether it has enough is known once the points have passed
    its start (only points seen before it count), so each batch's rows wait in ``held``
    until every event in them is final, then go out filtered. The wait is bounded by
    max_lookahead_s of rows."""
    min_points = config.tables.min_points_per_wheel
    counts = np.zeros((events.num_rows, 2), dtype=np.int64)
    t_start = events.column("t_start_ns").to_numpy().astype(np.int64)
    held: deque[MatchedBatch] = deque()
    distinct_points = 0

    def release(matched: MatchedBatch) -> None:
        scored = counts.min(axis=1) >= min_points
        keep = np.take(scored, matched.event_row)
        points_writer.write(matched.table if keep.all() else matched.table.filter(pa.array(keep)))

    for matched in event_points_of_log(
        li,
        config.model.wheel_window_radius_m,
        config.tables.max_lookahead_s,
        config.vehicle.track_m,
    ):
        counts += matched.counts
        distinct_points += matched.distinct
        if matched.table.num_rows:
            held.append(matched)
        # Points come in time order (to within a scan: FINAL_MARGIN_NS): every point seen
        # before an event starting this long before the batch's last one is in.
        final_ns = matched.t_hi_ns - FINAL_MARGIN_NS
        while held and int(t_start[held[0].event_row].max()) <= final_ns:
            release(held.popleft())
    while held:
        release(held.popleft())
    return counts, distinct_points


@dataclass
class _Totals:
    """Per split: the events, the rough ones and the point rows kept; and the events
    dropped for too few points."""

    events: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    rough: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    points: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    rejected: int = 0

    def splits(self) -> dict[str, SplitTotals]:
        """The totals by split name."""
        return {
            name: SplitTotals(self.events[name], self.rough[name], self.points[name])
            for name in ("train", "test")
        }


def _write_events(
    logs: list[LogInputs],
    events_by_log: list[pa.Table],
    split_of: list[NDArray[np.str_]],
    counts_by_log: list[NDArray[np.int64]],
    config: TablesSettings,
    events_writer: TableWriter,
) -> _Totals:
    """Write the scorable events of every log with their split and points per tyre."""
    min_points = config.tables.min_points_per_wheel
    keep_by_log = [
        c.min(axis=1) >= min_points if c.size else np.zeros(0, bool) for c in counts_by_log
    ]
    totals = _Totals(rejected=int(sum((~k).sum() for k in keep_by_log)))
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
            totals.events[name] += int(mine.sum())
            totals.rough[name] += int(rough[mine].sum())
            totals.points[name] += int(counts[keep][mine].sum())
    return totals


def _write_tables(
    call: Call[TablesSettings],
    logs: list[LogInputs],
    events_by_log: list[pa.Table],
    timings: dict[str, float],
) -> tuple[_Totals, int]:
    """Both tables, written aside and published when both are complete (aborted on any
    error): the totals and the distinct points."""
    config = call.settings
    workspace, cfg_hash = call.workspace, call.config_hash
    split_of = _splits(events_by_log, config)
    sources = [li.hashes["events"] for li in logs]
    points_writer = TableWriter(
        workspace.event_points_table, "event_points", source_sha256=sources, config_hash=cfg_hash
    )
    events_writer = TableWriter(
        workspace.events_table, "tables_events", source_sha256=sources, config_hash=cfg_hash
    )
    t0 = time.perf_counter()
    try:
        counts_by_log: list[NDArray[np.int64]] = []
        distinct_points = 0
        for li, events in zip(logs, events_by_log, strict=True):
            counts, distinct = _match_log(li, events, config, points_writer)
            counts_by_log.append(counts)
            distinct_points += distinct
        points_writer.finish()
        timings["match"] = time.perf_counter() - t0
        totals = _write_events(logs, events_by_log, split_of, counts_by_log, config, events_writer)
        events_writer.finish()
        points_writer.publish()
        events_writer.publish()
    except BaseException:
        points_writer.abort()
        events_writer.abort()
        raise
    return totals, distinct_points


def _compute(call: Call[TablesSettings]) -> Made[TablesResult]:
    """Write the two tables (the module docstring); the runner records them."""
    config = call.settings
    workspace, start = call.workspace, call.start
    logs, warnings = call.found
    outputs = [workspace.events_table, workspace.event_points_table]
    events_by_log = [
        read_table(LogFiles(li.log_dir).events, "events", columns=list(EVENT_COLUMNS))
        for li in logs
    ]
    timings: dict[str, float] = {}
    totals, distinct_points = _write_tables(call, logs, events_by_log, timings)
    splits = totals.splits()
    rejected = totals.rejected
    rejects = {"too_few_points": rejected}
    if rejected:
        warnings.append(
            f"{rejected} events dropped: fewer than {config.tables.min_points_per_wheel} "
            "points under a tyre"
        )
    row_counts: dict[str, int] = {}
    for name, t in splits.items():
        row_counts[f"{name}_events"] = t.events
        row_counts[f"{name}_positives"] = t.rough  # the manifest's key, as ever
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


__all__ = [
    "EVENT_COLUMNS",
    "SPEC",
    "STAGE",
    "PathSource",
    "RunningUnwrap",
    "SplitTotals",
    "TablesResult",
    "TyrePaths",
    "tyre_paths",
]

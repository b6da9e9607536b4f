"""The tyre patches of the events online learning replays, read a window of events at a
time: what keeps the online stage's memory flat however long the drive.

- :func:`point_extent` makes one light pass over the event points (five of their columns,
  batch by batch): when each event's last point was seen, the most points under one tyre,
  and every laser's name.
- :class:`PatchWindows` then serves the replay's requests for patches (``take``, as
  :class:`~toolkit.model.patches.TyrePatches` does) from a window of ``window`` events in
  driven order, read anew when a request leaves it. Only the row groups of
  ``tables/event_points.parquet`` whose footer statistics can hold the window's events are
  read (the tables stage writes the points in (log, event) order), so a read costs a
  window, not the table. Every window's patches are conformed to the same lasers and
  width, so patches of different windows join (the buffer holds events of many).

A patch is sampled from its own event's points alone (:func:`~toolkit.model.patches.
build_patches`: the lowest of a per-point hash under the laser's rank, per tyre), so an
event's patch is the same read in any window as read with every event at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
import polars as pl
import pyarrow as pa

from toolkit.arrays import IntArray
from toolkit.config import ModelConfig
from toolkit.model.patches import POINT_COLUMNS, TyrePatches, build_patches
from toolkit.stages.training_data import DICTIONARY_COLUMNS, POINT_BATCH
from toolkit.tableio import iter_table_batches, row_group_ranges
from toolkit.workspace import Workspace

#: Events a window holds: about 3 km of race driving (0.7 events a metre), ~10 MB of
#: patches at 40 points a tyre, and its pairs ~80 MB while they are scored.
WINDOW_EVENTS = 2048
#: A new window starts this share of a window before the first event asked for: the labels
#: learned from in a step belong to events seen up to a label's latency (~1 s) before it.
WINDOW_BACK = 1 / 8
#: Rows a window's read decodes at a time: a window's ~1.5 M points in a dozen batches, so
#: that the read's transient memory (the batch and the sampling's arrays over it) stays
#: small beside the window's patches.
WINDOW_BATCH = 131_072
#: ``last_seen_ns`` of an event without points.
NO_POINT = np.iinfo(np.int64).min


@dataclass(frozen=True)
class PointExtent:
    """What one light pass over the event points says of the events (E,): when each one's
    last point was seen (ns, :data:`NO_POINT` without any), the most points under one tyre
    of any event, and every laser's name (sorted)."""

    last_seen_ns: IntArray
    widest: int
    lasers: tuple[str, ...]


def point_extent(workspace: Workspace, events: pa.Table) -> PointExtent:
    """:class:`PointExtent` of ``events`` (a table with ``log_id`` and ``event_id``), its
    rows in order, from ``tables/event_points.parquet`` streamed in batches."""
    columns = ["log_id", "event_id", "wheel", "laser", "t_ns"]
    keys = ["log_id", "event_id", "wheel"]
    parts: list[pl.DataFrame] = []
    lasers: set[str] = set()
    for batch in iter_table_batches(
        workspace.event_points_table,
        "event_points",
        columns=columns,
        batch_rows=POINT_BATCH,
        as_dictionary=[c for c in DICTIONARY_COLUMNS if c in columns],
    ):
        lasers.update(str(n) for n in batch.column("laser").dictionary.to_pylist())
        frame = cast(pl.DataFrame, pl.from_arrow(pa.table(batch).select([*keys, "t_ns"])))
        got = frame.group_by(keys).agg(pl.col("t_ns").max().alias("last"), pl.len().alias("n"))
        parts.append(got.with_columns(pl.col("log_id", "wheel").cast(pl.String)))
    schema = {"log_id": pl.String, "event_id": pl.Int64, "wheel": pl.String}
    tyres = (
        pl.concat(parts)
        .group_by(keys)
        .agg(pl.col("last").max(), pl.col("n").sum())
        .cast({"event_id": pl.Int64})
        if parts
        else pl.DataFrame(schema={**schema, "last": pl.Int64, "n": pl.UInt32})
    )
    per_event = tyres.group_by(["log_id", "event_id"]).agg(pl.col("last").max())
    asked = pl.DataFrame(
        {
            "log_id": events.column("log_id").to_pylist(),
            "event_id": events.column("event_id").to_numpy().astype(np.int64),
            "row": np.arange(events.num_rows, dtype=np.int64),
        },
        schema={"log_id": pl.String, "event_id": pl.Int64, "row": pl.Int64},
    )
    joined = asked.join(per_event, on=["log_id", "event_id"], how="left").sort("row")
    last = joined.get_column("last").fill_null(NO_POINT).to_numpy().astype(np.int64)
    widest = int(tyres.get_column("n").fill_null(0).to_numpy().max(initial=0))
    return PointExtent(last, widest, tuple(sorted(lasers)))


class PatchWindows:
    """The patches of ``events`` (rows in driven order) as the replay asks for them
    (module docstring), read a window at a time; ``reads`` counts the reads."""

    def __init__(
        self,
        workspace: Workspace,
        events: pa.Table,
        model: ModelConfig,
        laser_order: Sequence[str],
        extent: PointExtent,
        window: int = WINDOW_EVENTS,
    ) -> None:
        self._path = workspace.event_points_table
        self._events = events
        self._log = np.asarray(events.column("log_id").to_pylist(), dtype=object)
        self._id = events.column("event_id").to_numpy().astype(np.int64)
        self._model, self._order, self._lasers = model, tuple(laser_order), extent.lasers
        k = model.max_points_per_wheel
        self._width = max(k or extent.widest, 2)  # as build_patches pads a patch
        self._window = window
        self._logs = _ranges(row_group_ranges(self._path, "event_points", "log_id"), "")
        self._ids = _ranges(row_group_ranges(self._path, "event_points", "event_id"), 0)
        self._cached: tuple[int, TyrePatches] | None = None
        self.reads = 0

    @property
    def events(self) -> int:
        return int(self._events.num_rows)

    def take(self, groups: IntArray) -> TyrePatches:
        """The patches of ``groups`` (group ``2 e + w``: event ``e``'s wheel ``w``), in that
        order: from the window held when it holds them; else from a new window from just
        before them, when they fit in one; else read for themselves alone."""
        groups = np.asarray(groups, np.int64)
        if groups.size == 0:
            return self._read(np.zeros(0, np.int64))
        lo, hi = int(groups.min()) // 2, int(groups.max()) // 2 + 1
        cached = self._cached
        if cached is not None and cached[0] <= lo and hi <= cached[0] + cached[1].events:
            return cached[1].take(groups - 2 * cached[0])
        start = max(0, lo - int(WINDOW_BACK * self._window))
        if hi - start <= self._window:
            stop = min(self.events, start + self._window)
            self._cached = (start, self._read(np.arange(start, stop, dtype=np.int64)))
            return self._cached[1].take(groups - 2 * start)
        rows, inverse = np.unique(groups // 2, return_inverse=True)
        return self._read(rows).take(2 * inverse.reshape(-1) + groups % 2)

    def _read(self, rows: IntArray) -> TyrePatches:
        """The patches of the events ``rows``, from the row groups that can hold them."""
        self.reads += 1
        batches = iter_table_batches(
            self._path,
            "event_points",
            columns=list(POINT_COLUMNS),
            batch_rows=WINDOW_BATCH,
            as_dictionary=list(DICTIONARY_COLUMNS),
            row_groups=self._row_groups(rows),
        )
        patches = build_patches(
            self._events.take(pa.array(rows)),
            batches,
            self._model.max_points_per_wheel,
            sample=self._model.point_sample,
            laser_order=self._order,
            source=self._path,
        )
        return patches.conform(self._lasers, self._width)

    def _row_groups(self, rows: IntArray) -> list[int]:
        """The row groups whose statistics allow a point of an event of ``rows`` (every
        one without statistics)."""
        (log_lo, log_hi, log_known), (id_lo, id_hi, id_known) = self._logs, self._ids
        chosen = np.zeros(log_known.size, bool)
        for log in dict.fromkeys(self._log[rows].tolist()):
            mine = self._id[rows][self._log[rows] == log]
            holds_log = ~log_known | ((log_lo <= log) & (log_hi >= log))
            holds_id = ~id_known | ((id_hi >= mine.min()) & (id_lo <= mine.max()))
            chosen |= holds_log & holds_id
        return np.flatnonzero(chosen).tolist()


def _ranges(
    ranges: list[tuple[object, object] | None], blank: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row groups' (min, max) as arrays of mins and maxes (``blank`` where unknown) and
    a mask of the known ones."""
    known = np.array([r is not None for r in ranges], bool)
    lo = np.array([blank if r is None else r[0] for r in ranges], dtype=object)
    hi = np.array([blank if r is None else r[1] for r in ranges], dtype=object)
    return lo, hi, known


__all__ = ["NO_POINT", "PatchWindows", "PointExtent", "WINDOW_EVENTS", "point_extent"]

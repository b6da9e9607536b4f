"""Tyre patches: the laser points the model scores for each event and rear tyre (sect. 4).

Section 4 scores, per rear tyre and separately, the ``N`` laser points "near the predicted
future location" of that tyre; ``tables/event_points.parquet`` lists them (sect. 7: within
30 cm of the ground the tyre traversed). This module turns that long table into a dense,
padded layout every later computation can vectorise over::

    group g = 2 * event_index + wheel          (wheel 0 = left, 1 = right)
    x, y, z, tau, gamma, psi : (G, n_max) float64, one row per group, points in columns
    lead                     : (G, n_max) float64, s the point was seen before its event
    valid                    : (G, n_max) bool, False in the padding
    count                    : (G,) int64, the points kept per group

**How many points.** The score of eq. (2) compares every pair: ``N (N - 1) / 2`` of them. The
paper's tables hold 887,878 points for 11,470 training events (sect. 7), 39 points a tyre;
Stanley's five 75 Hz lasers simulated here put about 380 under a tyre (see
``benchmarks/README.md``), a hundred times the pairs. ``[model] max_points_per_wheel`` (40 by
default, the paper's density) caps ``N``: a patch with more points keeps a uniform sample of
them. The sample is *bottom-k by a hash of the point's identity* (its time ``t_ns`` and its
laser's name): deterministic and independent of row order. It is a coordinated sample: a
point has the same rank-key in every patch it lies in, so patches listing the same points
keep the same ones, and overlapping patches prefer the same points. 0 keeps every point (the
padded width is then the largest patch). ``[model] point_sample`` chooses which points:

- ``"hash"`` (the paper's reading: sect. 7 uses "data from all lasers"): the uniform sample
  above. About 14 of a tyre's 40 points are then the nearest laser's and the rest the far
  lasers', whose within-cell height differences are mostly range and attitude error.
- ``"nearest_laser"``: the lasers ranked by how soon before their event their points were
  seen (:func:`lead_order`, the mean lead time over the training events), and a patch keeps
  the nearest laser's points first, then the next laser's, each laser's by the hash order
  above. The nearest laser is the least noisy (sect. 7.1: "the closest, most accurate
  laser"); the far ones fill a patch only where it has fewer points.
- ``"freshest"``: the points seen last before the event (the shortest lead time per point).
  On a 24-mile race log (seed 507) it scored worse on the test split than the hash sample
  (AUC 0.53 against 0.57, with the paper's search).

Nothing here knows the model's parameters; :mod:`toolkit.model.roughness` scores patches.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.errors import StageError

WHEELS = ("left", "right")
#: How a patch with more than n_max points is thinned (module docstring).
SAMPLES = ("hash", "freshest", "nearest_laser")
#: Columns of ``tables/event_points.parquet`` a patch is built from.
POINT_COLUMNS = (
    "log_id",
    "event_id",
    "wheel",
    "x",
    "y",
    "z",
    "tau",
    "roll_rate",
    "pitch_rate",
    "laser",
    "t_ns",
)


@dataclass(frozen=True)
class TyrePatches:
    """The points under each event's rear tyres, padded to ``n_max`` per group.

    Attributes (G = 2 x events; group ``2 e + w`` is event ``e``'s wheel ``w``):
        x, y, z: (G, n_max) point position in the pose's world frame, m.
        tau: (G, n_max) observation time, s (eq. 1's tau).
        gamma, psi: (G, n_max) estimated roll and pitch rate at that time, rad/s.
        lead: (G, n_max) how long before its event began the point was seen, s (the
            event's ``t_start_ns`` less the point's ``t_ns``; 0 when the events table has no
            start times; None in patches built by hand). The optional look-ahead term of
            :mod:`toolkit.model.roughness`.
        valid: (G, n_max) True where a point is (padding is False).
        count: (G,) points per group.
        laser: (G, n_max) int16 index into ``lasers`` (-1 in the padding).
        lasers: the laser topics, sorted.
    """

    x: FloatArray
    y: FloatArray
    z: FloatArray
    tau: FloatArray
    gamma: FloatArray
    psi: FloatArray
    valid: BoolArray
    count: IntArray
    laser: NDArray[np.int16]
    lasers: tuple[str, ...]
    lead: FloatArray | None = None

    @property
    def groups(self) -> int:
        return int(self.valid.shape[0])

    @property
    def events(self) -> int:
        return self.groups // 2

    @property
    def n_max(self) -> int:
        return int(self.valid.shape[1])

    def take(self, groups: slice | BoolArray | IntArray) -> TyrePatches:
        """The patches of the rows ``groups`` (a slice, a (G,) mask or row indices), same
        width n_max."""
        return TyrePatches(
            self.x[groups],
            self.y[groups],
            self.z[groups],
            self.tau[groups],
            self.gamma[groups],
            self.psi[groups],
            self.valid[groups],
            self.count[groups],
            self.laser[groups],
            self.lasers,
            None if self.lead is None else self.lead[groups],
        )

    def join(self, other: TyrePatches) -> TyrePatches:
        """These patches, then ``other``'s (the same lasers and width n_max); the
        look-ahead is kept only if both have it."""
        if other.lasers != self.lasers or other.n_max != self.n_max:
            raise ValueError("patches of other lasers or another width cannot be joined")

        def both(name: str) -> np.ndarray:
            return np.concatenate([getattr(self, name), getattr(other, name)])

        return TyrePatches(
            x=both("x"),
            y=both("y"),
            z=both("z"),
            tau=both("tau"),
            gamma=both("gamma"),
            psi=both("psi"),
            valid=both("valid"),
            count=both("count"),
            laser=both("laser"),
            lasers=self.lasers,
            lead=None if self.lead is None or other.lead is None else both("lead"),
        )

    def conform(self, lasers: tuple[str, ...], n_max: int) -> TyrePatches:
        """The same patches over ``lasers`` (sorted names, a superset of this one's) and
        ``n_max`` points wide (at least this one's): patches built apart (a window of
        events at a time) made joinable. ValueError if either would lose a point."""
        missing = set(self.lasers) - set(lasers)
        if missing or n_max < self.n_max or list(lasers) != sorted(lasers):
            raise ValueError(
                f"patches of lasers {self.lasers} and width {self.n_max} do not fit lasers "
                f"{lasers} and width {n_max}"
            )
        to_new = np.array([lasers.index(n) for n in self.lasers] + [-1], np.int16)
        pad = ((0, 0), (0, n_max - self.n_max))

        def wide(a: np.ndarray) -> np.ndarray:
            return np.pad(a, pad) if pad[1][1] else a

        return TyrePatches(
            wide(self.x),
            wide(self.y),
            wide(self.z),
            wide(self.tau),
            wide(self.gamma),
            wide(self.psi),
            wide(self.valid),
            self.count,
            np.pad(to_new[self.laser], pad, constant_values=-1),  # -1 (padding) stays -1
            lasers,
            None if self.lead is None else wide(self.lead),
        )

    def with_z(self, z: FloatArray) -> TyrePatches:
        """The same patches with other heights (G, n_max) (the oracle's true terrain)."""
        return TyrePatches(
            self.x,
            self.y,
            np.asarray(z, np.float64),
            self.tau,
            self.gamma,
            self.psi,
            self.valid,
            self.count,
            self.laser,
            self.lasers,
            self.lead,
        )


def point_priority(t_ns: NDArray[np.int64], laser_code: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """A pseudo-random, reproducible rank (N,) for points (N,) from their identity: the
    SplitMix64 finaliser (Steele, Lea and Flood 2014) of ``t_ns`` mixed with a code of the
    laser's name (:func:`laser_code`)."""
    with np.errstate(over="ignore"):
        v = t_ns.astype(np.uint64) ^ (laser_code.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15))
        v = (v ^ (v >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        v = (v ^ (v >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        out: NDArray[np.uint64] = v ^ (v >> np.uint64(31))
        return out


def laser_code(name: str) -> int:
    """A stable number for a laser's topic (CRC-32 of its UTF-8 bytes): the same on every
    run and whatever other lasers a table holds."""
    return zlib.crc32(name.encode("utf-8"))


@dataclass
class _Kept:
    """Rows that may still be among their patch's n_max (column arrays of equal length)."""

    group: IntArray
    priority: NDArray[np.uint64]
    values: dict[str, FloatArray]
    laser: NDArray[np.int64]  # index of each row's laser in the run's laser list


def _bottom_k(group: IntArray, priority: NDArray[np.uint64], k: int) -> IntArray:
    """Indices of the rows that are among the ``k`` lowest priorities of their group
    (all rows when ``k`` is 0), ordered by (group, priority)."""
    order = np.lexsort((priority, group))
    if k == 0:
        return order
    g = group[order]
    first = np.r_[True, g[1:] != g[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(g.size), 0))
    return order[np.arange(g.size) - start < k]


_VALUE_COLUMNS = {
    "x": "x",
    "y": "y",
    "z": "z",
    "tau": "tau",
    "gamma": "roll_rate",
    "psi": "pitch_rate",
}


def _codes(column: pa.Array | pa.ChunkedArray) -> tuple[IntArray, list[str | None]]:
    """A string column as (N,) indices into its distinct values (the list), -1 for null.

    Read as a dictionary (``iter_table_batches(as_dictionary=...)``) the column already is
    one; a plain one is encoded here. Either way no string per row is ever made."""
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    if not pa.types.is_dictionary(column.type):
        column = pc.dictionary_encode(column)
    indices = column.indices.fill_null(-1).to_numpy(zero_copy_only=False).astype(np.int64)
    return indices, [None if v is None else str(v) for v in column.dictionary.to_pylist()]


class _EventIndex:
    """Where each (log_id, event_id) of ``events`` sits in it: a sorted key per log, looked
    up with ``np.searchsorted`` (no join of string columns per batch)."""

    def __init__(self, events: pa.Table, source: str | Path) -> None:
        codes, names = _codes(events.column("log_id"))
        event_id = np.asarray(events.column("event_id").to_numpy(zero_copy_only=False), np.int64)
        self.logs: dict[str, tuple[IntArray, IntArray]] = {}
        for code, name in enumerate(names):
            if name is None:
                continue
            rows = np.flatnonzero(codes == code)
            order = np.argsort(event_id[rows], kind="stable")
            ids = event_id[rows][order]
            if ids.size > 1 and (ids[1:] == ids[:-1]).any():
                dup = int(ids[1:][ids[1:] == ids[:-1]][0])
                raise StageError(f"log {name!r} lists event {dup} twice", path=source)
            self.logs[name] = (ids, rows[order])

    def lookup(
        self, log_codes: IntArray, log_names: list[str | None], event_id: IntArray
    ) -> IntArray:
        """(N,) the event index of each row, -1 for events not in the table."""
        out = np.full(event_id.size, -1, np.int64)
        for code, name in enumerate(log_names):
            known = self.logs.get(name) if name is not None else None
            if known is None:
                continue
            ids, index = known
            rows = np.flatnonzero(log_codes == code)
            if rows.size == 0 or ids.size == 0:
                continue
            at = np.minimum(np.searchsorted(ids, event_id[rows]), ids.size - 1)
            hit = ids[at] == event_id[rows]
            out[rows[hit]] = index[at[hit]]
        return out


def _point_batches(
    points: pa.Table | Iterable[pa.RecordBatch | pa.Table], index: _EventIndex
) -> Iterator[tuple[pa.Table, IntArray, tuple[IntArray, list[str | None]]]]:
    """Each non-empty batch of event points as (table, its rows' event indices (-1: not
    asked for), its laser column as codes and names)."""
    batches = points.to_batches() if isinstance(points, pa.Table) else points
    for batch in batches:
        table = pa.table(batch) if isinstance(batch, pa.RecordBatch) else batch
        if table.num_rows == 0:
            continue
        log_codes, log_names = _codes(table.column("log_id"))
        event_id = np.asarray(table.column("event_id").to_numpy(zero_copy_only=False), np.int64)
        event = index.lookup(log_codes, log_names, event_id)
        yield table, event, _codes(table.column("laser"))


@dataclass(frozen=True)
class _Sampling:
    """How ``build_patches`` picks the points of a patch, fixed once for all batches.

    Attributes:
        k: ``max_points_per_wheel`` (0: every point).
        sample: one of :data:`SAMPLES`.
        only_laser: the one laser kept, or None for all.
        rank_of: laser name -> its rank in ``laser_order`` (nearest first).
        start_ns: (E,) the events' ``t_start_ns``, or None when the table has none.
        source: the path named in errors.
    """

    k: int
    sample: str
    only_laser: str | None
    rank_of: dict[str, int]
    start_ns: IntArray | None
    source: str | Path

    @property
    def fresh_from_ns(self) -> IntArray | None:
        """The start times the freshest sample ranks by (None for the other samples)."""
        return self.start_ns if self.sample == "freshest" else None


def _sampling(
    events: pa.Table,
    max_points_per_wheel: int,
    only_laser: str | None,
    sample: str,
    laser_order: Sequence[str],
    source: str | Path,
) -> _Sampling:
    """The checked sampling options of ``build_patches``; ValueError for an unknown
    ``sample``, or the freshest sample without the events' start times."""
    if sample not in SAMPLES:
        raise ValueError(f"sample must be one of {SAMPLES}, not {sample!r}")
    rank_of = {name: i for i, name in enumerate(laser_order)}
    # The events' start times: each point's look-ahead, and the freshest sample's order.
    if sample == "freshest" and "t_start_ns" not in events.column_names:
        raise ValueError("the freshest sample needs the events' t_start_ns")
    start_ns = (
        np.asarray(events.column("t_start_ns").to_numpy(zero_copy_only=False), np.int64)
        if "t_start_ns" in events.column_names
        else None
    )
    return _Sampling(max_points_per_wheel, sample, only_laser, rank_of, start_ns, source)


def _rows_asked(
    event: IntArray, laser_codes: IntArray, laser_names: list[str | None], only_laser: str | None
) -> IntArray:
    """The rows of a batch that belong to an event asked for (and to ``only_laser``)."""
    keep = event >= 0
    if only_laser is not None:
        keep &= laser_codes == (laser_names.index(only_laser) if only_laser in laser_names else -2)
    return np.flatnonzero(keep)


def _wheels(table: pa.Table, rows: IntArray, source: str | Path) -> IntArray:
    """(N,) the wheel (0 left, 1 right) of each of ``rows``; StageError for any other."""
    wheel_codes, wheel_names = _codes(table.column("wheel"))
    to_wheel = np.array([WHEELS.index(n) if n in WHEELS else -1 for n in wheel_names] + [-1])
    wheel: IntArray = to_wheel[wheel_codes[rows]]  # a null wheel (-1) takes the last entry, -1
    if (wheel < 0).any():
        bad = wheel_codes[rows][wheel < 0][0]
        raise StageError(
            f"wheel {wheel_names[bad] if bad >= 0 else None!r} is neither 'left' nor 'right'",
            path=source,
        )
    return wheel


def _values(table: pa.Table, rows: IntArray, source: str | Path) -> dict[str, FloatArray]:
    """The scored columns (``_VALUE_COLUMNS``) of ``rows`` as float64; StageError for a
    non-finite value."""
    values: dict[str, FloatArray] = {}
    for key, col in _VALUE_COLUMNS.items():
        v = np.asarray(
            table.column(col).cast(pa.float64()).to_numpy(zero_copy_only=False), np.float64
        )[rows]
        if not np.isfinite(v).all():
            bad_count = int(np.count_nonzero(~np.isfinite(v)))
            raise StageError(
                f"column {col!r}: {bad_count} non-finite value(s) (e.g. "
                f"{v[~np.isfinite(v)][0]!r}); the model cannot score them",
                path=source,
            )
        values[key] = v
    return values


def _priority(
    t_ns: IntArray,
    event: IntArray,
    laser_codes: IntArray,
    names: list[str],
    sampling: _Sampling,
) -> NDArray[np.uint64]:
    """(N,) each row's rank-key in its patch, lowest kept first (module docstring): the
    coordinated hash, under the laser's rank (nearest laser) or the lead time (freshest)."""
    codes = np.array([laser_code(n) for n in names], np.uint64)[laser_codes]
    priority = point_priority(t_ns, codes)
    if sampling.sample == "nearest_laser":
        # The laser's rank above, the hash's high 48 bits below: a laser's points all
        # come before the next laser's, each laser's in the coordinated hash order.
        rank_of = sampling.rank_of
        rank = np.array([rank_of.get(n, len(rank_of)) for n in names], np.uint64)
        priority = (rank[laser_codes] << np.uint64(48)) | (priority >> np.uint64(16))
    fresh_from_ns = sampling.fresh_from_ns
    if fresh_from_ns is not None:
        # Lead time in microseconds above, the hash's low 20 bits below: the points seen
        # last before the event, ties broken reproducibly.
        lead_us = (fresh_from_ns[event] - t_ns) // 1000
        priority = (np.maximum(lead_us, 0).astype(np.uint64) << np.uint64(20)) | (
            priority & np.uint64(0xFFFFF)
        )
    return priority


def _kept_of_batch(
    table: pa.Table,
    event: IntArray,
    laser_codes: IntArray,
    laser_names: list[str | None],
    sampling: _Sampling,
    laser_ids: dict[str, int],
) -> _Kept | None:
    """The rows of one batch that may be among their patch's k (None if it has none);
    names the lasers of those rows in ``laser_ids`` (name -> index, by first appearance)."""
    source = sampling.source
    rows = _rows_asked(event, laser_codes, laser_names, sampling.only_laser)
    if rows.size == 0:
        return None
    event, laser_codes = event[rows], laser_codes[rows]
    group = event * 2 + _wheels(table, rows, source)
    if (laser_codes < 0).any():
        raise StageError("a point has no laser name", path=source)
    names = [str(n) for n in laser_names]
    # Only the lasers of the rows taken (the events asked for, ``only_laser``) are named
    # in the result, not every name in the batch's dictionary.
    ids = np.full(len(names), -1, np.int64)
    for code in np.unique(laser_codes):
        ids[code] = laser_ids.setdefault(names[code], len(laser_ids))
    values = _values(table, rows, source)
    t_ns = np.asarray(table.column("t_ns").to_numpy(zero_copy_only=False), np.int64)[rows]
    start_ns = sampling.start_ns
    values["lead"] = (
        np.asarray((start_ns[event] - t_ns) * 1e-9, np.float64)
        if start_ns is not None
        else np.zeros(rows.size)
    )
    priority = _priority(t_ns, event, laser_codes, names, sampling)
    take = _bottom_k(group, priority, sampling.k)
    return _Kept(
        group[take],
        priority[take],
        {key: v[take] for key, v in values.items()},
        ids[laser_codes][take],
    )


def _dense_patches(
    kept: list[_Kept], laser_ids: dict[str, int], n_groups: int, k: int
) -> TyrePatches:
    """The padded (G, n_max) layout of the rows among their patch's k over all batches;
    the lasers renumbered from first appearance to sorted names."""
    group = np.concatenate([c.group for c in kept]) if kept else np.zeros(0, np.int64)
    priority = np.concatenate([c.priority for c in kept]) if kept else np.zeros(0, np.uint64)
    take = _bottom_k(group, priority, k)
    g = group[take]
    count_all = np.bincount(g, minlength=n_groups).astype(np.int64)
    n_max = max(k or int(count_all.max(initial=0)), 2)
    start = np.concatenate([[0], np.cumsum(count_all)[:-1]])
    cols = np.arange(g.size, dtype=np.int64) - start[g]

    def dense(key: str) -> FloatArray:
        out = np.zeros((n_groups, n_max), np.float64)
        if kept:
            out[g, cols] = np.concatenate([c.values[key] for c in kept])[take]
        return out

    # Laser indices by first appearance -> indices into the sorted names.
    first_seen = list(laser_ids)
    lasers = tuple(sorted(first_seen))
    to_sorted = np.array([lasers.index(n) for n in first_seen], np.int64)
    valid = np.zeros((n_groups, n_max), bool)
    valid[g, cols] = True
    laser = np.full((n_groups, n_max), -1, np.int16)
    if g.size:
        seen = np.concatenate([c.laser for c in kept])[take]
        laser[g, cols] = to_sorted[seen]
    return TyrePatches(
        x=dense("x"),
        y=dense("y"),
        z=dense("z"),
        tau=dense("tau"),
        gamma=dense("gamma"),
        psi=dense("psi"),
        valid=valid,
        count=count_all,
        laser=laser,
        lasers=lasers,
        lead=dense("lead"),
    )


def build_patches(
    events: pa.Table,
    points: pa.Table | Iterable[pa.RecordBatch | pa.Table],
    max_points_per_wheel: int,
    *,
    only_laser: str | None = None,
    sample: str = "hash",
    laser_order: Sequence[str] = (),
    source: str | Path = "tables/event_points.parquet",
) -> TyrePatches:
    """Patches for ``events`` (a table with ``log_id`` and ``event_id``, in the order the
    result's groups follow) from the rows of ``tables/event_points.parquet``: a table, or
    record batches streamed from it (memory then holds only the rows that may be kept: at
    most ``max_points_per_wheel`` per patch and batch).

    ``only_laser`` keeps that laser's points alone (the baseline's closest laser, sect. 7.1).
    ``sample`` is how a patch is thinned (module docstring); ``"nearest_laser"`` ranks the
    lasers as ``laser_order`` lists them (nearest first; lasers not listed come last).
    Points of events not in ``events`` are ignored. StageError if a point names a wheel other
    than left or right, or a column the model scores holds a non-finite value.
    """
    sampling = _sampling(events, max_points_per_wheel, only_laser, sample, laser_order, source)
    index = _EventIndex(events, source)
    kept: list[_Kept] = []
    laser_ids: dict[str, int] = {}  # laser name -> index, in order of first appearance
    for table, event, (laser_codes, laser_names) in _point_batches(points, index):
        batch = _kept_of_batch(table, event, laser_codes, laser_names, sampling, laser_ids)
        if batch is not None:
            kept.append(batch)
    return _dense_patches(kept, laser_ids, 2 * events.num_rows, max_points_per_wheel)


def lead_order(
    events: pa.Table,
    points: pa.Table | Iterable[pa.RecordBatch | pa.Table],
    source: str | Path = "tables/event_points.parquet",
) -> tuple[str, ...]:
    """The lasers of the points under ``events`` (a table with ``log_id``, ``event_id`` and
    ``t_start_ns``), nearest first: ordered by the mean time their points were seen before
    their event began (ties by name). A mean, because it streams: a laser's look-ahead is
    fixed by its mount, so the lasers' lead times overlap little and the mean orders them
    as the median would. The one ranking of the lasers: the model's nearest-laser sample
    and the race test's closest laser both take it."""
    index = _EventIndex(events, source)
    start_ns = np.asarray(events.column("t_start_ns").to_numpy(zero_copy_only=False), np.int64)
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for table, event, (laser_codes, laser_names) in _point_batches(points, index):
        t_ns = np.asarray(table.column("t_ns").to_numpy(zero_copy_only=False), np.int64)
        ok = (event >= 0) & (laser_codes >= 0)
        lead_s = (start_ns[event[ok]] - t_ns[ok]) * 1e-9
        code = laser_codes[ok]
        total = np.bincount(code, weights=lead_s, minlength=len(laser_names))
        n = np.bincount(code, minlength=len(laser_names))
        for i, name in enumerate(laser_names):
            if name is not None and n[i]:
                sums[name] = sums.get(name, 0.0) + float(total[i])
                counts[name] = counts.get(name, 0) + int(n[i])
    return tuple(sorted(sums, key=lambda name: (sums[name] / counts[name], name)))


__all__ = [
    "POINT_COLUMNS",
    "WHEELS",
    "TyrePatches",
    "build_patches",
    "laser_code",
    "lead_order",
    "point_priority",
]

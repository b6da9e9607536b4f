"""Fig. 4 from the log itself: how far two scans of the same ground disagree in height, against
the time between them (paper sect. 3, Fig. 4).

The paper motivates the time term of its difference function (eq. 4) with "the measured
z-difference from two scans of flat terrain graphed against the time between the scans": the
pose error, and with it the height of the projected ground, drifts, so two scans of one patch
disagree more the longer apart they were taken. This module measures exactly that from a
projected point cloud (``points.parquet``), streaming, for any log.

Method (each choice with its reason)
------------------------------------
*Cells.* The ground is cut into square cells of ``cell_m`` (default 0.2 m) in the world x, y,
keyed by a spatial hash ``key = ix * 2**32 + (iy mod 2**32)``, ``ix = floor(x / cell_m)``.
0.2 m is about one laser footprint: beams are 0.5 deg apart (0.17 m across the track at 20 m)
and a 75 Hz scan line advances 0.13 m at 10 m/s, so a cell is hit by about one beam of each
scan that crosses it. Smaller cells leave most cells with a single scan; larger ones put
points of a pair farther apart, so terrain slope ``g`` adds up to ``sqrt(2) cell_m g`` to
``|dz|`` (1.4 cm at a 5 % grade for 0.2 m) that is not pose error.

*Observations.* The points of one scan that fall in one cell are averaged into one
observation (mean z, mean beam time; ``n`` points). A scan is one laser's sweep,
identified by ``(laser, scan_t_ns)``. A cell with many points of one scan (near range, or a
slow vehicle) therefore weighs as one observation, and no pair is ever made within a scan:
two points of one sweep share their pose error, which is not what Fig. 4 measures.

*Pairs.* An observation is paired with earlier observations (earlier scans in stream order) of
the same cell whose scan stamps are less than ``max_dt_s`` (default 10 s) older. Scans of any
two lasers count (Stanley's five lasers look 6-25 m ahead, so the same ground is seen by the
far laser first and the near ones up to a few seconds later; the same laser's consecutive
scans give the short separations). A pair's time is the difference of the two observations'
beam times, ``dt = |t_i - t_j|``; its height difference is the later minus the earlier,
``dz = z_later - z_earlier``. 10 s is more than a vehicle at racing speed needs to drive past
a cell; pairs beyond it would come from revisits (loops), a different question.

*No cell dominates.* Each observation takes at most ``pairs_per_observation`` (K, default 8)
of its candidates: all of them if there are at most K, else K spread evenly by rank over the
window, ``i = lo + floor((2k + 1) n / 2K)``, k = 0..K-1, for the n candidates from ``lo`` on
(deterministic, and covering the whole window in time, not just the most recent scans).
Driving, a cell gets about 5-15 observations, so nearly all its pairs are taken; a vehicle
standing still sees its cells with every scan, and K caps those to the same number of pairs
per observation - every observation, hence every second of log, weighs about the same.

*Flat ground only.* Like the paper's figure, only locally flat ground is used, judged within
each scan line (which alone sees the ground at one instant, free of pose drift): a point is
flat when the chord from beam ``b - w`` to ``b + w`` (``w = flat_window_beams``, all beams
present) rises at most ``max_slope`` over its horizontal length, and no beam between departs
from the chord by more than ``max_bump_m``. This removes rocks, ruts, kerbs and steep banks,
where two hits 0.2 m apart legitimately differ in height; a pose error tilts a whole scan line
by a fraction of a degree (slope < 0.01) and leaves it straight, so it passes the test. Points
at a scan's ends or next to a dropped return (flatness unknown) are left out.
``flat_window_beams = 0`` switches the test off.

*Bins and fits.* Pairs are binned by ``dt`` in ``bin_s`` (default 0.1 s) bins on
``[0, max_dt_s)``; per bin: count, mean ``dt``, mean / median / 90th percentile of ``|dz|``,
mean ``dz`` (a bias: the ground rising or sinking with time) and RMS ``dz``. Medians and
percentiles come from a fixed histogram of ``|dz|`` (``dz_resolution_m`` bins up to
``dz_max_m``, then one overflow bin), so memory is fixed and they are exact to the bin,
linearly interpolated within it. The figure's fit is weighted least squares of the bin medians
against the bins' mean ``dt`` (bins of at least ``min_bin_pairs`` pairs, each weighted by its
pairs): the median makes it robust to the obstacles that slip through the flatness test, the
weights keep every pair's say equal so the few pairs of the long-``dt`` bins (which come from
unusual stretches: slow driving, turns) do not carry the line. The unweighted fit of the
medians and the least squares of all pairs' ``|dz|`` against ``dt`` (from running sums) are
reported too.
All of it per laser pair class: the same laser, different lasers, and all pairs.

Streaming and memory
--------------------
:class:`ScanAgreement` is fed batches of points in the order the project stage writes them
(scans by stamp, beams in order), then asked for its :meth:`~ScanAgreement.result`. A batch may
end inside a scan: the last scan of each batch is held back until the next batch (or the
result) completes it, so the result does not depend on how the stream is cut into batches
(up to float summation order). Observations whose scan is more than ``max_dt_s`` older than
the newest scan can pair with nothing to come and are evicted - a cell not seen for
``max_dt_s`` is gone - so memory holds at most ``max_dt_s`` of observations (about 0.7 M
for five 181-beam lasers at 75 Hz) plus the fixed histograms, however long the log.
Everything is vectorised per batch (sorts, ``reduceat``, ``bincount``); deterministic.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import ArrayLike, NDArray

from toolkit.analysis.fig4 import (
    ALL_PAIRS,
    CLASS_NAMES,
    Fig4Bins,
    ScanAgreementConfig,
    ScanAgreementResult,
    fig4_bins,
)
from toolkit.analysis.scan_cells import (
    Observations,
    Points,
    first_at_or_after,
    flat_mask,
    observe,
    scan_starts,
)
from toolkit.arrays import IntArray
from toolkit.errors import StageError
from toolkit.tableio import iter_table_batches

#: Columns of points.parquet this analysis reads.
COLUMNS = ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
#: Rows per read batch when streaming a table: large enough to amortise the re-sort of the
#: window of observations (~0.7 M) each batch, ~60 MB of arrays in flight.
BATCH_ROWS = 1_048_576


class ScanAgreement:
    """Streaming Fig. 4 accumulator (see the module docstring): :meth:`feed` batches of points
    in stream order, then :meth:`result` once."""

    def __init__(self, config: ScanAgreementConfig | None = None) -> None:
        self.config = config or ScanAgreementConfig()
        c = self.config
        self._max_dt_ns = round(c.max_dt_s * 1e9)
        self._laser_codes: dict[str, int] = {}
        self._pending: Points | None = None  # the last, maybe incomplete, scan
        self._last_scan: tuple[int, int] | None = None  # (scan_t_ns, laser) of the newest row
        self._next_seq = 0
        self._window = Observations()
        self._finished = False
        shape = (len(CLASS_NAMES), c.n_dt_bins)
        self._count = np.zeros(shape, np.int64)
        self._sums = {name: np.zeros(shape) for name in ("dt", "dt2", "abs", "dz", "dz2", "dt_abs")}
        self._hist = np.zeros((*shape, c.n_dz_bins + 1), np.int64)
        self.points = 0
        self.flat_points = 0
        self.observations = 0
        self.pairs = 0
        self.pairs_beyond = 0
        self.max_live_observations = 0
        self._seconds = 0.0

    @property
    def live_observations(self) -> int:
        """Observations currently held (those that can still pair with what is to come)."""
        return self._window.size

    @property
    def live_cells(self) -> int:
        """Distinct cells currently held."""
        return int(np.unique(self._window.key).size)

    # ---- input ------------------------------------------------------------------------

    def feed(self, batch: pa.Table | pa.RecordBatch | Mapping[str, ArrayLike]) -> None:
        """Add a batch of points: a table or record batch of ``points.parquet`` rows, or a
        mapping of equal-length arrays, with at least ``t_ns``, ``laser``, ``beam``, ``x``,
        ``y``, ``z``, ``scan_t_ns`` (``beam`` may be left out when ``flat_window_beams`` is
        0). Batches come in stream order: scans by stamp, each scan's points contiguous."""
        if self._finished:
            raise StageError("scan agreement: feed() after result(); start a new accumulator")
        start = time.perf_counter()
        points = self._as_points(batch)
        self.points += points.size
        if points.size:
            self._check_order(points)
            if self._pending is not None:
                points = Points.concat(self._pending, points)
            # The rows of the last scan may continue in the next batch: hold them back.
            last = scan_starts(points)[-1]
            self._pending = points.slice(int(last))
            self._process(points.slice(0, int(last)))
        self._seconds += time.perf_counter() - start

    def result(self) -> ScanAgreementResult:
        """Finish the stream (the held-back last scan is processed) and compute the bins and
        fits. Ends the accumulator: a later :meth:`feed` is an error."""
        start = time.perf_counter()
        if not self._finished:
            if self._pending is not None:
                self._process(self._pending)
                self._pending = None
            self._finished = True
            self._window = Observations()
        classes = {ALL_PAIRS: self._bins(ALL_PAIRS, slice(None))}
        for k, name in enumerate(CLASS_NAMES):
            classes[name] = self._bins(name, slice(k, k + 1))
        self._seconds += time.perf_counter() - start
        return ScanAgreementResult(
            config=self.config,
            classes=classes,
            points=self.points,
            flat_points=self.flat_points,
            observations=self.observations,
            pairs=self.pairs,
            pairs_beyond_max_dt=self.pairs_beyond,
            max_live_observations=self.max_live_observations,
            seconds=self._seconds,
        )

    def _as_points(self, batch: pa.Table | pa.RecordBatch | Mapping[str, ArrayLike]) -> Points:
        need_beam = self.config.flat_window_beams > 0
        names = [c for c in COLUMNS if need_beam or c != "beam"]
        have = batch.schema.names if isinstance(batch, pa.Table | pa.RecordBatch) else batch
        missing = [c for c in names if c not in have]
        if missing:
            raise StageError(f"scan agreement: the points have no column {missing[0]!r}")

        def col(name: str, dtype: type) -> NDArray[Any]:
            if isinstance(batch, pa.Table | pa.RecordBatch):
                return np.asarray(batch.column(name).to_numpy(zero_copy_only=False), dtype)
            return np.asarray(batch[name], dtype)

        t_ns = col("t_ns", np.int64)
        n = t_ns.size
        return Points(
            t_ns=t_ns,
            laser=self._codes(batch["laser"]),
            beam=col("beam", np.int64) if need_beam else np.zeros(n, np.int64),
            x=col("x", np.float64),
            y=col("y", np.float64),
            z=col("z", np.float64),
            scan_t_ns=col("scan_t_ns", np.int64),
        )

    def _codes(self, lasers: Any) -> IntArray:
        """Laser names (an Arrow or numpy column) -> small integer codes, stable over the
        stream (a loop over the distinct names of a batch, not over points)."""
        if isinstance(lasers, pa.ChunkedArray | pa.Array):
            encoded = pc.dictionary_encode(lasers)
            chunks = encoded.chunks if isinstance(encoded, pa.ChunkedArray) else [encoded]
            parts = []
            for chunk in chunks:
                names = chunk.dictionary.to_pylist()
                table = np.array([self._code(str(s)) for s in names], np.int64)
                parts.append(table[chunk.indices.to_numpy(zero_copy_only=False)])
            return np.concatenate(parts) if parts else np.zeros(0, np.int64)
        names, inverse = np.unique(np.asarray(lasers).astype(str), return_inverse=True)
        table = np.array([self._code(str(s)) for s in names], np.int64)
        return table[inverse.ravel()] if names.size else np.zeros(0, np.int64)

    def _code(self, name: str) -> int:
        return self._laser_codes.setdefault(name, len(self._laser_codes))

    def _check_order(self, p: Points) -> None:
        if np.any(np.diff(p.scan_t_ns) < 0) or (
            self._last_scan is not None and int(p.scan_t_ns[0]) < self._last_scan[0]
        ):
            raise StageError(
                "scan agreement: points are not in scan order (scans by stamp, as the "
                "project stage writes them)"
            )
        self._last_scan = (int(p.scan_t_ns[-1]), int(p.laser[-1]))

    # ---- processing of complete scans -------------------------------------------------

    def _process(self, p: Points) -> None:
        if p.size == 0:
            return
        c = self.config
        starts = scan_starts(p)
        is_start = np.zeros(p.size, np.int64)
        is_start[starts] = 1
        seq = self._next_seq + np.cumsum(is_start) - 1
        self._next_seq = int(seq[-1]) + 1
        flat = (
            flat_mask(p.x, p.y, p.z, p.beam, seq, c.flat_window_beams, c.max_slope, c.max_bump_m)
            if c.flat_window_beams > 0
            else np.ones(p.size, bool)
        )
        keep = np.flatnonzero(flat)
        self.flat_points += keep.size
        new = observe(p, seq, keep, c.cell_m)
        self.observations += new.size
        newest_scan_ns = int(p.scan_t_ns[-1])
        if self._pending is not None and self._pending.size:
            newest_scan_ns = max(newest_scan_ns, int(self._pending.scan_t_ns[0]))
        if new.size:
            self._pair(new)
        # Evict what can pair with nothing to come: future scans are no older than newest.
        alive = self._window.scan_t_ns >= newest_scan_ns - self._max_dt_ns
        if not alive.all():
            self._window = self._window.take(np.flatnonzero(alive))

    def _pair(self, new: Observations) -> None:
        """Pair the new observations with the window's and with each other, accumulate the
        pairs, and add the new ones to the window (kept sorted by cell, then scan)."""
        c = self.config
        # Every new observation is of a later scan than every held one (seq grows with the
        # stream), so within its cell it sorts after them: the sorted window and the sorted
        # new ones merge, each new one going after the held ones of its cell (no sort of
        # the whole window per batch: that was most of Fig. 4's cost).
        new = new.take(np.lexsort((new.seq, new.key)))
        p = np.searchsorted(self._window.key, new.key, side="right") + np.arange(new.size)
        both = Observations.merge(self._window, new, p)
        self._window = both
        self.max_live_observations = max(self.max_live_observations, both.size)

        # For each new observation at position p: the first position lo of its cell whose
        # scan is less than max_dt older. Sorted by (key, seq), stamps are non-decreasing
        # within a cell, so its candidates are exactly positions lo..p-1.
        # Strictly less (the bins cover [0, max_dt)).
        q = both.scan_t_ns[p] - self._max_dt_ns + 1
        lo = first_at_or_after(both.key, both.scan_t_ns, p, q)
        n = p - lo
        m = np.minimum(n, c.pairs_per_observation)
        total = int(m.sum())
        if total == 0:
            return
        owner = np.repeat(np.arange(p.size), m)
        k = np.arange(total) - np.repeat(np.cumsum(m) - m, m)
        mo, no = m[owner], n[owner]
        i = lo[owner] + ((2 * k + 1) * no) // (2 * mo)  # evenly by rank; all when n <= K
        j = p[owner]
        self._accumulate(both, i, j)

    def _accumulate(self, obs: Observations, i: IntArray, j: IntArray) -> None:
        c = self.config
        dt_ns = obs.t_ns[j] - obs.t_ns[i]
        dz = obs.z_m[j] - obs.z_m[i]
        dz = np.where(dt_ns >= 0, dz, -dz)  # later minus earlier
        dt = np.abs(dt_ns) * 1e-9
        cls = (obs.laser[i] != obs.laser[j]).astype(np.int64)
        b = np.floor(dt / c.bin_s).astype(np.int64)
        inside = b < c.n_dt_bins
        self.pairs += int(i.size)
        self.pairs_beyond += int((~inside).sum())
        if not inside.all():
            dt, dz, cls, b = dt[inside], dz[inside], cls[inside], b[inside]
        a = np.abs(dz)
        flat = cls * c.n_dt_bins + b
        size = self._count.size
        self._count.ravel()[:] += np.bincount(flat, minlength=size)
        for name, w in (
            ("dt", dt),
            ("dt2", dt * dt),
            ("abs", a),
            ("dz", dz),
            ("dz2", dz * dz),
            ("dt_abs", dt * a),
        ):
            self._sums[name].ravel()[:] += np.bincount(flat, weights=w, minlength=size)
        h = np.minimum(np.floor(a / c.dz_resolution_m), c.n_dz_bins).astype(np.int64)
        n_h = c.n_dz_bins + 1
        self._hist.ravel()[:] += np.bincount(flat * n_h + h, minlength=self._hist.size)

    # ---- the result ---------------------------------------------------------------------

    def _bins(self, name: str, classes: slice) -> Fig4Bins:
        """The bins of the pair classes ``classes`` (a slice of the accumulators' first
        axis), named ``name``."""
        count = self._count[classes].sum(axis=0)
        s = {k: v[classes].sum(axis=0) for k, v in self._sums.items()}
        hist = self._hist[classes].sum(axis=0)
        return fig4_bins(name, self.config, count, s, hist)


def scan_agreement_of(
    points_path: Path,
    config: ScanAgreementConfig | None = None,
    *,
    batch_rows: int = BATCH_ROWS,
) -> ScanAgreementResult:
    """Fig. 4 of a ``points.parquet`` table, streamed in batches of ``batch_rows`` rows."""
    acc = ScanAgreement(config)
    columns = [c for c in COLUMNS if acc.config.flat_window_beams > 0 or c != "beam"]
    for batch in iter_table_batches(points_path, "points", columns=columns, batch_rows=batch_rows):
        acc.feed(batch)
    return acc.result()


__all__ = ["BATCH_ROWS", "COLUMNS", "ScanAgreement", "scan_agreement_of"]

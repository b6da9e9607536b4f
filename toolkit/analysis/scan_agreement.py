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

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import ArrayLike, NDArray

from toolkit.analysis.figures import new_figure, save_png_atomic, write_csv_atomic
from toolkit.errors import ConfigError, StageError
from toolkit.tableio import iter_table_batches

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Columns of points.parquet this analysis reads.
COLUMNS = ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
#: Rows per read batch when streaming a table: large enough to amortise the re-sort of the
#: window of observations (~0.7 M) each batch, ~60 MB of arrays in flight.
BATCH_ROWS = 1_048_576
#: Pair classes, in the order of the accumulators' first axis.
SAME_LASER, DIFFERENT_LASER = 0, 1
CLASS_NAMES = ("same_laser", "different_laser")
#: Name of the class that adds both.
ALL_PAIRS = "all"
CSV_NAME = "fig4_z_difference_vs_dt.csv"
PNG_NAME = "fig4_z_difference_vs_dt.png"
_CELL_INDEX_LIMIT = 2**31  # |ix|, |iy| below this keep the hash key unique in int64


@dataclass(frozen=True)
class ScanAgreementConfig:
    """Parameters of the Fig. 4 measurement (see the module docstring for each choice)."""

    cell_m: float = 0.2
    max_dt_s: float = 10.0
    bin_s: float = 0.1
    pairs_per_observation: int = 8
    flat_window_beams: int = 3
    max_slope: float = 0.1
    max_bump_m: float = 0.03
    dz_resolution_m: float = 0.001
    dz_max_m: float = 1.0
    min_bin_pairs: int = 30

    def __post_init__(self) -> None:
        positive = ("cell_m", "max_dt_s", "bin_s", "dz_resolution_m", "dz_max_m")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"scan agreement: {name} must be positive, got {value!r}")
        if self.pairs_per_observation < 1:
            raise ConfigError(
                "scan agreement: pairs_per_observation must be at least 1, "
                f"got {self.pairs_per_observation!r}"
            )
        if self.flat_window_beams < 0 or self.min_bin_pairs < 1:
            raise ConfigError(
                "scan agreement: flat_window_beams must be >= 0 and min_bin_pairs >= 1, got "
                f"{self.flat_window_beams!r}, {self.min_bin_pairs!r}"
            )
        if not (self.max_slope >= 0 and self.max_bump_m >= 0):
            raise ConfigError(
                "scan agreement: max_slope and max_bump_m must be >= 0, got "
                f"{self.max_slope!r}, {self.max_bump_m!r}"
            )

    @property
    def n_dt_bins(self) -> int:
        """Bins of ``bin_s`` covering ``[0, max_dt_s)`` (the last may reach past it)."""
        return max(1, math.ceil(self.max_dt_s / self.bin_s - 1e-9))

    @property
    def n_dz_bins(self) -> int:
        """Histogram bins of ``|dz|`` below ``dz_max_m``; one overflow bin follows them."""
        return max(1, math.ceil(self.dz_max_m / self.dz_resolution_m - 1e-9))


@dataclass(frozen=True)
class LinearFit:
    """``y = slope * dt + intercept`` by ordinary least squares over ``n`` points (bins or
    pairs); NaN when fewer than two distinct ``dt`` were available."""

    slope_m_per_s: float
    intercept_m: float
    r2: float
    n: int

    def describe(self) -> str:
        """E.g. ``|dz| = 0.41 cm/s dt + 1.20 cm (r2 0.93, 98 bins)``."""
        return (
            f"|dz| = {100 * self.slope_m_per_s:.3g} cm/s dt + {100 * self.intercept_m:.3g} cm "
            f"(r2 {self.r2:.3f}, n {self.n})"
        )


@dataclass(frozen=True, eq=False)
class Fig4Bins:
    """The non-empty ``dt`` bins of one pair class (``pairs``: ``"all"``, ``"same_laser"``
    or ``"different_laser"``); every array has shape (B,), B bins with at least one pair."""

    pairs: str
    dt_lo_s: FloatArray
    dt_hi_s: FloatArray
    count: IntArray
    mean_dt_s: FloatArray
    mean_abs_dz_m: FloatArray
    median_abs_dz_m: FloatArray
    p90_abs_dz_m: FloatArray
    mean_dz_m: FloatArray
    rms_dz_m: FloatArray
    #: The figure's fit: bin medians (bins of >= min_bin_pairs pairs) against mean dt, each
    #: bin weighted by its pairs.
    fit_medians: LinearFit
    #: The same with every bin weighing the same (the sparse long-dt bins count fully).
    fit_medians_unweighted: LinearFit
    #: All pairs' |dz| against dt.
    fit_pairs: LinearFit

    @property
    def pairs_total(self) -> int:
        return int(self.count.sum())


@dataclass(frozen=True, eq=False)
class ScanAgreementResult:
    """Fig. 4 of one log: the bins per pair class and what went into them."""

    config: ScanAgreementConfig
    #: "all", "same_laser", "different_laser".
    classes: Mapping[str, Fig4Bins]
    points: int
    flat_points: int
    observations: int
    pairs: int
    #: Pairs whose beam times were ``max_dt_s`` or more apart (pairs are windowed by scan
    #: stamps, and beam times can be a few ms farther apart); not binned.
    pairs_beyond_max_dt: int
    #: Most observations held at once (the bounded memory).
    max_live_observations: int
    seconds: float

    @property
    def fit(self) -> LinearFit:
        """The figure's fit over all pairs (bin medians against dt)."""
        return self.classes[ALL_PAIRS].fit_medians

    def summary(self) -> str:
        return (
            f"Fig. 4: {self.fit.describe()}; {self.pairs} pairs from {self.observations} "
            f"observations of {self.flat_points} flat points (of {self.points})"
        )


# --------------------------------------------------------------------------------------
# The accumulator
# --------------------------------------------------------------------------------------


@dataclass
class _Observations:
    """Observations (one per cell and scan), struct of arrays, each (M,)."""

    key: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    seq: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    scan_t_ns: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    t_ns: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    z_m: FloatArray = field(default_factory=lambda: np.zeros(0, np.float64))
    laser: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def size(self) -> int:
        return int(self.key.size)

    def take(self, idx: NDArray[Any]) -> _Observations:
        return _Observations(
            self.key[idx],
            self.seq[idx],
            self.scan_t_ns[idx],
            self.t_ns[idx],
            self.z_m[idx],
            self.laser[idx],
        )

    @staticmethod
    def merge(a: _Observations, b: _Observations, at: IntArray) -> _Observations:
        """``a`` and ``b`` as one, ``b``'s rows at positions ``at`` (ascending, (len(b),))
        of the result and ``a``'s rows, in their order, everywhere else."""
        from_a = np.ones(a.size + b.size, bool)
        from_a[at] = False
        fields = []
        for n in ("key", "seq", "scan_t_ns", "t_ns", "z_m", "laser"):
            va, vb = getattr(a, n), getattr(b, n)
            out = np.empty(from_a.size, va.dtype)
            out[at] = vb
            out[from_a] = va
            fields.append(out)
        return _Observations(*fields)


@dataclass
class _Points:
    """A stretch of points in stream order, struct of arrays, each (N,)."""

    t_ns: IntArray
    laser: IntArray
    beam: IntArray
    x: FloatArray
    y: FloatArray
    z: FloatArray
    scan_t_ns: IntArray

    @property
    def size(self) -> int:
        return int(self.t_ns.size)

    def slice(self, lo: int, hi: int | None = None) -> _Points:
        return _Points(
            *(
                getattr(self, n)[lo:hi]
                for n in ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
            )
        )

    @staticmethod
    def concat(a: _Points, b: _Points) -> _Points:
        return _Points(
            *(
                np.concatenate([getattr(a, n), getattr(b, n)])
                for n in ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
            )
        )


class ScanAgreement:
    """Streaming Fig. 4 accumulator (see the module docstring): :meth:`feed` batches of points
    in stream order, then :meth:`result` once."""

    def __init__(self, config: ScanAgreementConfig | None = None) -> None:
        self.config = config or ScanAgreementConfig()
        c = self.config
        self._max_dt_ns = round(c.max_dt_s * 1e9)
        self._laser_codes: dict[str, int] = {}
        self._pending: _Points | None = None  # the last, maybe incomplete, scan
        self._last_scan: tuple[int, int] | None = None  # (scan_t_ns, laser) of the newest row
        self._next_seq = 0
        self._window = _Observations()
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
                points = _Points.concat(self._pending, points)
            # The rows of the last scan may continue in the next batch: hold them back.
            last = _scan_starts(points)[-1]
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
            self._window = _Observations()
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

    def _as_points(self, batch: pa.Table | pa.RecordBatch | Mapping[str, ArrayLike]) -> _Points:
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
        return _Points(
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

    def _check_order(self, p: _Points) -> None:
        if np.any(np.diff(p.scan_t_ns) < 0) or (
            self._last_scan is not None and int(p.scan_t_ns[0]) < self._last_scan[0]
        ):
            raise StageError(
                "scan agreement: points are not in scan order (scans by stamp, as the "
                "project stage writes them)"
            )
        self._last_scan = (int(p.scan_t_ns[-1]), int(p.laser[-1]))

    # ---- processing of complete scans -------------------------------------------------

    def _process(self, p: _Points) -> None:
        if p.size == 0:
            return
        c = self.config
        starts = _scan_starts(p)
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
        new = _observe(p, seq, keep, c.cell_m)
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

    def _pair(self, new: _Observations) -> None:
        """Pair the new observations with the window's and with each other, accumulate the
        pairs, and add the new ones to the window (kept sorted by cell, then scan)."""
        c = self.config
        # Every new observation is of a later scan than every held one (seq grows with the
        # stream), so within its cell it sorts after them: the sorted window and the sorted
        # new ones merge, each new one going after the held ones of its cell (no sort of
        # the whole window per batch: that was most of Fig. 4's cost).
        new = new.take(np.lexsort((new.seq, new.key)))
        p = np.searchsorted(self._window.key, new.key, side="right") + np.arange(new.size)
        both = _Observations.merge(self._window, new, p)
        self._window = both
        self.max_live_observations = max(self.max_live_observations, both.size)

        # For each new observation at position p: the first position lo of its cell whose
        # scan is less than max_dt older. Sorted by (key, seq), stamps are non-decreasing
        # within a cell, so its candidates are exactly positions lo..p-1.
        # Strictly less (the bins cover [0, max_dt)).
        q = both.scan_t_ns[p] - self._max_dt_ns + 1
        lo = _first_at_or_after(both.key, both.scan_t_ns, p, q)
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

    def _accumulate(self, obs: _Observations, i: IntArray, j: IntArray) -> None:
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
        c = self.config
        count = self._count[classes].sum(axis=0)
        s = {k: v[classes].sum(axis=0) for k, v in self._sums.items()}
        hist = self._hist[classes].sum(axis=0)
        nz = np.flatnonzero(count)
        n = count[nz].astype(np.float64)
        lo = nz * c.bin_s
        median = np.array([_hist_quantile(hist[b], 0.5, c.dz_resolution_m) for b in nz])
        p90 = np.array([_hist_quantile(hist[b], 0.9, c.dz_resolution_m) for b in nz])
        mean_dt = s["dt"][nz] / n
        fit_ok = count[nz] >= c.min_bin_pairs
        weights = count[nz][fit_ok].astype(np.float64)
        fit_medians = _ols(mean_dt[fit_ok], median[fit_ok], weights)
        fit_medians_unweighted = _ols(mean_dt[fit_ok], median[fit_ok])
        fit_pairs = _ols_from_sums(
            float(count.sum()),
            float(s["dt"].sum()),
            float(s["dt2"].sum()),
            float(s["abs"].sum()),
            float(s["dt_abs"].sum()),
            float(s["dz2"].sum()),
        )
        return Fig4Bins(
            pairs=name,
            dt_lo_s=lo.astype(np.float64),
            dt_hi_s=np.minimum(lo + c.bin_s, max(c.max_dt_s, c.bin_s)).astype(np.float64),
            count=count[nz].astype(np.int64),
            mean_dt_s=mean_dt,
            mean_abs_dz_m=s["abs"][nz] / n,
            median_abs_dz_m=median.astype(np.float64),
            p90_abs_dz_m=p90.astype(np.float64),
            mean_dz_m=s["dz"][nz] / n,
            rms_dz_m=np.sqrt(s["dz2"][nz] / n),
            fit_medians=fit_medians,
            fit_medians_unweighted=fit_medians_unweighted,
            fit_pairs=fit_pairs,
        )


# --------------------------------------------------------------------------------------
# Vectorised pieces
# --------------------------------------------------------------------------------------


def _scan_starts(p: _Points) -> IntArray:
    """Row indices (S,) where a scan starts: ``(laser, scan_t_ns)`` changes."""
    change = (np.diff(p.scan_t_ns) != 0) | (np.diff(p.laser) != 0)
    return np.concatenate([[0], np.flatnonzero(change) + 1]).astype(np.int64)


def flat_mask(
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    beam: IntArray,
    scan: IntArray,
    window_beams: int,
    max_slope: float,
    max_bump_m: float,
) -> NDArray[np.bool_]:
    """Points (N,) on locally flat ground, judged within their scan line: the points of each
    scan contiguous, beams ascending. With ``w = window_beams``, point ``b`` is flat when beams
    ``b - w .. b + w`` of its scan are all present and the chord from ``b - w`` to ``b + w``
    has ``|dz| <= max_slope * hypot(dx, dy)`` and every beam between lies within
    ``max_bump_m`` of the chord (interpolated by beam index: on flat ground the beams are
    about evenly spaced over so short a stretch). A loop over the ``2w + 1`` offsets, not
    over points."""
    n = z.size
    w = window_beams
    flat = np.zeros(n, bool)
    if n <= 2 * w:
        return flat
    c = np.arange(w, n - w)  # centres with a full window of rows
    a, b = c - w, c + w
    ok = (scan[a] == scan[b]) & (beam[b] - beam[a] == 2 * w)
    rise = z[b] - z[a]
    ok &= np.abs(rise) <= max_slope * np.hypot(x[b] - x[a], y[b] - y[a])
    for k in range(1, 2 * w):
        ok &= np.abs(z[a + k] - (z[a] + rise * (k / (2 * w)))) <= max_bump_m
    flat[c] = ok
    return flat


def cell_keys(x: FloatArray, y: FloatArray, cell_m: float) -> IntArray:
    """Spatial hash (N,) of the ``cell_m`` square cells of points (x, y) m:
    ``ix * 2**32 + (iy mod 2**32)``, unique for cell indices below 2**31 in magnitude."""
    ix = np.floor(x / cell_m)
    iy = np.floor(y / cell_m)
    if ix.size and (
        not (np.isfinite(ix).all() and np.isfinite(iy).all())
        or max(np.abs(ix).max(), np.abs(iy).max()) >= _CELL_INDEX_LIMIT
    ):
        raise StageError(
            "scan agreement: point coordinates are not finite or are farther than "
            f"{_CELL_INDEX_LIMIT * cell_m:.3g} m from the origin"
        )
    return (ix.astype(np.int64) << 32) + (iy.astype(np.int64) & 0xFFFFFFFF)


def _observe(p: _Points, seq: IntArray, keep: IntArray, cell_m: float) -> _Observations:
    """One observation per (cell, scan) of the points ``keep``: mean z, mean beam time."""
    if keep.size == 0:
        return _Observations()
    key = cell_keys(p.x[keep], p.y[keep], cell_m)
    s = seq[keep]
    order = np.lexsort((key, s))  # rows are in scan order already: by cell within a scan
    key, s, rows = key[order], s[order], keep[order]
    start = np.flatnonzero(np.r_[True, (np.diff(key) != 0) | (np.diff(s) != 0)])
    count = np.diff(np.r_[start, key.size])
    scan_t = p.scan_t_ns[rows[start]]
    # Beam-time offsets within a scan are small: summed as int64 without overflow.
    offset = np.add.reduceat(p.t_ns[rows] - p.scan_t_ns[rows], start)
    return _Observations(
        key=key[start],
        seq=s[start],
        scan_t_ns=scan_t,
        t_ns=scan_t + offset // count,
        z_m=np.add.reduceat(p.z[rows], start) / count,
        laser=p.laser[rows[start]],
    )


def _first_at_or_after(key: IntArray, t: IntArray, p: IntArray, q_t: IntArray) -> IntArray:
    """For rows sorted by (key, t) (W,) and queries at rows ``p`` (Q,): the first row of row
    ``p``'s key whose ``t`` is at least ``q_t`` (Q,), ``q_t <= t[p]`` (a searchsorted on two
    keys, exact in int64).

    The two keys become one sorted int64, ``rank(key) * span + (t - t_min)`` with ``span``
    more than the range of ``t``, so one ``searchsorted`` answers every query: linear in the
    rows, where sorting rows and queries together cost ``(W + Q) log (W + Q)`` per batch."""
    if key.size == 0:
        return np.zeros(p.size, np.int64)
    rank = np.cumsum(np.r_[0, (np.diff(key) != 0).astype(np.int64)])
    t_min = int(t.min())
    span = int(t.max()) - t_min + 1
    if int(rank[-1]) + 1 > (2**62) // span:  # the joint key would overflow: sort instead
        return _lower_bound(key, t, key[p], q_t)
    joint = rank * span + (t - t_min)
    wanted = rank[p] * span + np.maximum(q_t - t_min, 0)
    return np.searchsorted(joint, wanted, side="left").astype(np.int64)


def _lower_bound(key: IntArray, t: IntArray, q_key: IntArray, q_t: IntArray) -> IntArray:
    """For data sorted by (key, t) and queries (Q,), the number of data rows that sort before
    ``(q_key, q_t)`` lexicographically, i.e. the first row of the query's key with
    ``t >= q_t`` (a searchsorted on two keys, exact in int64, by one joint sort)."""
    n = key.size
    keys = np.concatenate([key, q_key])
    times = np.concatenate([t, q_t])
    # Queries sort before data with an equal (key, t): data at exactly q_t counts as inside.
    is_data = np.concatenate([np.ones(n, np.int64), np.zeros(q_key.size, np.int64)])
    order = np.lexsort((is_data, times, keys))
    before = np.cumsum(is_data[order]) - is_data[order]
    out = np.empty(q_key.size, np.int64)
    query_pos = np.flatnonzero(order >= n)
    out[order[query_pos] - n] = before[query_pos]
    return out


def _hist_quantile(hist: IntArray, q: float, width: float) -> float:
    """Quantile ``q`` of values histogrammed in bins ``[k w, (k + 1) w)`` (the last bin:
    overflow, reported at its lower edge), linear within the bin."""
    total = int(hist.sum())
    if total == 0:
        return math.nan
    target = q * total
    cum = np.cumsum(hist)
    k = int(np.searchsorted(cum, target, side="left"))
    k = min(k, hist.size - 1)
    if k == hist.size - 1 and hist.size > 1:
        below = int(cum[k - 1])
        if target > below:
            return float(k * width)
    prev = int(cum[k - 1]) if k else 0
    frac = (target - prev) / hist[k] if hist[k] else 0.0
    return float((k + frac) * width)


def _ols(x: FloatArray, y: FloatArray, w: FloatArray | None = None) -> LinearFit:
    """Least squares line through points (x, y), each of weight ``w`` (default 1); the
    fit's ``n`` is the number of points."""
    if x.size < 2 or np.ptp(x) == 0:
        return LinearFit(math.nan, math.nan, math.nan, int(x.size))
    w = np.ones_like(x) if w is None else np.asarray(w, np.float64)
    fit = _ols_from_sums(
        float(w.sum()),
        float((w * x).sum()),
        float((w * x * x).sum()),
        float((w * y).sum()),
        float((w * x * y).sum()),
        float((w * y * y).sum()),
    )
    return LinearFit(fit.slope_m_per_s, fit.intercept_m, fit.r2, int(x.size))


def _ols_from_sums(n: float, sx: float, sxx: float, sy: float, sxy: float, syy: float) -> LinearFit:
    """Least squares line from the sums: ``slope = Sxy / Sxx`` with the centred sums
    ``Sxx = sxx - sx^2/n``, ``Sxy = sxy - sx sy / n``; ``r2 = Sxy^2 / (Sxx Syy)``."""
    if n < 2:
        return LinearFit(math.nan, math.nan, math.nan, int(n))
    cxx = sxx - sx * sx / n
    cxy = sxy - sx * sy / n
    cyy = syy - sy * sy / n
    if cxx <= 0:
        return LinearFit(math.nan, math.nan, math.nan, int(n))
    slope = cxy / cxx
    intercept = (sy - slope * sx) / n
    r2 = cxy * cxy / (cxx * cyy) if cyy > 0 else math.nan
    return LinearFit(float(slope), float(intercept), float(r2), int(n))


# --------------------------------------------------------------------------------------
# A table, and the outputs
# --------------------------------------------------------------------------------------


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


CSV_HEADER = (
    "pairs",
    "dt_lo_s",
    "dt_hi_s",
    "count",
    "mean_dt_s",
    "mean_abs_dz_m",
    "median_abs_dz_m",
    "p90_abs_dz_m",
    "mean_dz_m",
    "rms_dz_m",
)


def write_fig4(result: ScanAgreementResult, out_dir: Path, log_id: str) -> tuple[Path, Path]:
    """Write :data:`CSV_NAME` (every non-empty bin of every pair class, one row each, columns
    :data:`CSV_HEADER`) and :data:`PNG_NAME` (bin medians of all pairs against dt with the
    fitted line, the two laser classes faintly behind) into ``out_dir``, each atomically.
    Returns the two paths."""
    out_dir = Path(out_dir)
    rows: list[tuple[object, ...]] = []
    for bins in result.classes.values():
        for k in range(bins.count.size):
            rows.append(
                (
                    bins.pairs,
                    float(bins.dt_lo_s[k]),
                    float(bins.dt_hi_s[k]),
                    int(bins.count[k]),
                    float(bins.mean_dt_s[k]),
                    float(bins.mean_abs_dz_m[k]),
                    float(bins.median_abs_dz_m[k]),
                    float(bins.p90_abs_dz_m[k]),
                    float(bins.mean_dz_m[k]),
                    float(bins.rms_dz_m[k]),
                )
            )
    csv_path = write_csv_atomic(out_dir / CSV_NAME, CSV_HEADER, rows)

    fig = new_figure()
    ax = fig.add_subplot(1, 1, 1)
    styles = {
        "same_laser": ("tab:orange", "same laser"),
        "different_laser": ("tab:green", "different lasers"),
    }
    for name, (colour, label) in styles.items():
        b = result.classes[name]
        ax.plot(
            b.mean_dt_s,
            b.median_abs_dz_m,
            ".",
            ms=3,
            color=colour,
            alpha=0.5,
            label=f"median |dz|, {label}",
        )
    allp = result.classes[ALL_PAIRS]
    ok = allp.count >= result.config.min_bin_pairs
    ax.plot(
        allp.mean_dt_s[ok],
        allp.median_abs_dz_m[ok],
        "o",
        ms=4,
        color="tab:blue",
        label=f"median |dz|, all pairs (bins of >= {result.config.min_bin_pairs})",
    )
    fit = allp.fit_medians
    if math.isfinite(fit.slope_m_per_s) and allp.count.size:
        xs = np.array([0.0, float(allp.dt_hi_s[ok].max() if ok.any() else allp.dt_hi_s.max())])
        ax.plot(
            xs,
            fit.intercept_m + fit.slope_m_per_s * xs,
            "-",
            color="black",
            lw=1.2,
            label="least-squares fit of the medians, bins weighted by pairs",
        )
    ax.set_xlabel("time between the two scans, dt (s)")
    ax.set_ylabel("z-difference of the same ground cell, |dz| (m)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3)
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(
        f"{log_id}: z-difference between scans of flat ground (cf. paper Fig. 4)\n"
        f"fit |dz| = {fit.slope_m_per_s:.4g} m/s x dt + {fit.intercept_m:.4g} m, "
        f"r2 = {fit.r2:.3f}; {result.pairs} pairs, {result.config.cell_m:g} m cells",
        fontsize=9,
    )
    fig.tight_layout()
    png_path = save_png_atomic(fig, out_dir / PNG_NAME)
    return csv_path, png_path


__all__ = [
    "ALL_PAIRS",
    "CLASS_NAMES",
    "COLUMNS",
    "CSV_HEADER",
    "CSV_NAME",
    "PNG_NAME",
    "Fig4Bins",
    "LinearFit",
    "ScanAgreement",
    "ScanAgreementConfig",
    "ScanAgreementResult",
    "cell_keys",
    "flat_mask",
    "scan_agreement_of",
    "write_fig4",
]

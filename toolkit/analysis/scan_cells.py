"""The vectorised pieces of the Fig. 4 measurement (:mod:`toolkit.analysis.scan_agreement`,
whose docstring gives each choice and its reason): points and observations as structs of
arrays, the scans of a stretch of points, the flatness test within a scan line, the cells'
spatial hash, one observation per cell and scan, and the two-key search of the window."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.errors import StageError

#: Names of :class:`Points`' columns, in its field order.
POINT_FIELDS = ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
_CELL_INDEX_LIMIT = 2**31  # |ix|, |iy| below this keep the hash key unique in int64


@dataclass
class Observations:
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

    def take(self, idx: NDArray[Any]) -> Observations:
        return Observations(
            self.key[idx],
            self.seq[idx],
            self.scan_t_ns[idx],
            self.t_ns[idx],
            self.z_m[idx],
            self.laser[idx],
        )

    @staticmethod
    def merge(a: Observations, b: Observations, at: IntArray) -> Observations:
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
        return Observations(*fields)


@dataclass
class Points:
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

    def slice(self, lo: int, hi: int | None = None) -> Points:
        return Points(*(getattr(self, n)[lo:hi] for n in POINT_FIELDS))

    @staticmethod
    def concat(a: Points, b: Points) -> Points:
        return Points(*(np.concatenate([getattr(a, n), getattr(b, n)]) for n in POINT_FIELDS))


def scan_starts(p: Points) -> IntArray:
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


def observe(p: Points, seq: IntArray, keep: IntArray, cell_m: float) -> Observations:
    """One observation per (cell, scan) of the points ``keep``: mean z, mean beam time."""
    if keep.size == 0:
        return Observations()
    key = cell_keys(p.x[keep], p.y[keep], cell_m)
    s = seq[keep]
    order = np.lexsort((key, s))  # rows are in scan order already: by cell within a scan
    key, s, rows = key[order], s[order], keep[order]
    start = np.flatnonzero(np.r_[True, (np.diff(key) != 0) | (np.diff(s) != 0)])
    count = np.diff(np.r_[start, key.size])
    scan_t = p.scan_t_ns[rows[start]]
    # Beam-time offsets within a scan are small: summed as int64 without overflow.
    offset = np.add.reduceat(p.t_ns[rows] - p.scan_t_ns[rows], start)
    return Observations(
        key=key[start],
        seq=s[start],
        scan_t_ns=scan_t,
        t_ns=scan_t + offset // count,
        z_m=np.add.reduceat(p.z[rows], start) / count,
        laser=p.laser[rows[start]],
    )


def first_at_or_after(key: IntArray, t: IntArray, p: IntArray, q_t: IntArray) -> IntArray:
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
        return lower_bound(key, t, key[p], q_t)
    joint = rank * span + (t - t_min)
    wanted = rank[p] * span + np.maximum(q_t - t_min, 0)
    return np.searchsorted(joint, wanted, side="left").astype(np.int64)


def lower_bound(key: IntArray, t: IntArray, q_key: IntArray, q_t: IntArray) -> IntArray:
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


__all__ = [
    "Observations",
    "Points",
    "cell_keys",
    "first_at_or_after",
    "flat_mask",
    "lower_bound",
    "observe",
    "scan_starts",
]

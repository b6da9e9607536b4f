"""Rows stamped far outside a log's own span: one stray stamp must not stretch the log.

A message stamped minutes or years away from the rest (a receiver that briefly reports a
wrong date, a log time beyond int64) sorts to one end of its table. Left there, it stretches
the log: later stages would allocate arrays across the void or extrapolate the pose into it.
Once a table is finished (sorted by t_ns), its ends are checked: a small group of rows cut off
from the rest by a long gap is rejected as ``time_outlier``. A long gap with plenty of data on
both sides is a sensor outage, not an outlier, and is kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from toolkit.tableio import ROW_GROUP_ROWS

#: Time outliers: rows at a table's ends cut off from the rest by more than this gap...
OUTLIER_GAP_NS = 60_000_000_000
#: ...and no more than this fraction of its rows (or OUTLIER_MIN_ROWS, if more).
OUTLIER_MAX_FRACTION = 0.001
OUTLIER_MIN_ROWS = 2


def _outlier_mask(n: int, gap_rows: Sequence[int]) -> np.ndarray:
    """The rule of :func:`time_outliers` from the row count and the rows that follow a long
    gap (ascending): the head before the first gap and the tail after the last, if small."""
    drop = np.zeros(n, dtype=bool)
    if not gap_rows or n < 3:
        return drop
    limit = max(OUTLIER_MIN_ROWS, int(OUTLIER_MAX_FRACTION * n))
    if gap_rows[0] <= limit:
        drop[: gap_rows[0]] = True
    if n - gap_rows[-1] <= limit:
        drop[gap_rows[-1] :] = True
    return drop


def time_outliers(t_ns: np.ndarray) -> np.ndarray:
    """Mask (n,) of the rows of a time-sorted column that are strays at either end: a group
    of at most ``max(OUTLIER_MIN_ROWS, OUTLIER_MAX_FRACTION * n)`` rows separated from the
    rest by a gap longer than :data:`OUTLIER_GAP_NS`."""
    gaps = np.diff(np.asarray(t_ns, dtype=np.int64))
    return _outlier_mask(len(t_ns), (np.flatnonzero(gaps > OUTLIER_GAP_NS) + 1).tolist())


def stream_time_outliers(path: Path) -> np.ndarray | None:
    """:func:`time_outliers` of a table's t_ns column, read a row group at a time so memory
    does not grow with the table; None when there are none."""
    n = 0
    last: int | None = None
    gap_rows: list[int] = []
    with pq.ParquetFile(path, pre_buffer=False) as f:
        for batch in f.iter_batches(batch_size=ROW_GROUP_ROWS, columns=["t_ns"]):
            t = batch.column(0).to_numpy()
            if not len(t):
                continue
            if last is not None and int(t[0]) - last > OUTLIER_GAP_NS:
                gap_rows.append(n)
            gap_rows.extend((n + np.flatnonzero(np.diff(t) > OUTLIER_GAP_NS) + 1).tolist())
            n += len(t)
            last = int(t[-1])
    drop = _outlier_mask(n, gap_rows)
    return drop if drop.any() else None


__all__ = [
    "OUTLIER_GAP_NS",
    "OUTLIER_MAX_FRACTION",
    "OUTLIER_MIN_ROWS",
    "stream_time_outliers",
    "time_outliers",
]

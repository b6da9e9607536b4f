"""A time-sorted table read forward, holding only the rows later requests can still need.

Stages that walk a log in time order (projection over scans, tables over points) need, for
each step, the pose rows around a stretch of time, and never the rows far behind. Reading
the pose whole would make their memory grow with the log; :class:`TimeWindow` reads it a
batch at a time instead (through :func:`toolkit.tableio.iter_table_batches`, so the table
is checked against its schema and its page checksums verified) and lets go of what is
behind.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from toolkit.tableio import iter_table_batches

Columns = dict[str, NDArray[Any]]
#: What a window may do to each batch's columns as it is read (in order), e.g. a running
#: unwrap of an angle: the columns in, the columns out (same names and lengths).
BatchTransform = Callable[[Columns], Columns]


class TimeWindow:
    """The rows of a table sorted by ``t_ns``, read forward a batch at a time.

    :meth:`rows` gives the rows from the last one at or before ``t_lo_ns`` to the first one
    at or after ``t_hi_ns`` (fewer at the table's ends), reading ahead as far as that needs;
    :meth:`forget_before` lets go of the rows before the last one at or before a time, after
    which no request may reach back before that time. Memory: the rows between the oldest
    time still wanted and the newest asked for, plus one read batch.
    """

    def __init__(
        self,
        path: Path,
        schema_name: str,
        *,
        columns: Sequence[str],
        batch_rows: int,
        transform: BatchTransform | None = None,
    ) -> None:
        """Read ``columns`` (``t_ns`` among them) of ``path``, a ``schema_name`` table;
        ``transform`` is applied to each batch's columns as read."""
        if "t_ns" not in columns:
            raise ValueError("a TimeWindow needs the t_ns column")
        self.path = path
        self._columns = tuple(columns)
        self._batches: Iterator[pa.RecordBatch] = iter_table_batches(
            path, schema_name, columns=self._columns, batch_rows=batch_rows
        )
        self._transform = transform
        self._cols: Columns | None = None
        self._done = False

    def _pull(self) -> bool:
        """Read one more batch; False at the table's end."""
        batch = next(self._batches, None)
        if batch is None:
            self._done = True
            return False
        new: Columns = {c: batch.column(c).to_numpy(zero_copy_only=False) for c in self._columns}
        new["t_ns"] = np.asarray(new["t_ns"], np.int64)
        if self._transform is not None:
            new = self._transform(new)
        if self._cols is None:
            self._cols = new
        else:
            self._cols = {c: np.concatenate([self._cols[c], new[c]]) for c in self._columns}
        return True

    def _t(self) -> NDArray[np.int64]:
        return self._cols["t_ns"] if self._cols is not None else np.zeros(0, np.int64)

    def rows(self, t_lo_ns: int, t_hi_ns: int) -> Columns:
        """Rows from the last one at or before ``t_lo_ns`` to the first one at or after
        ``t_hi_ns`` (views of the window's arrays, (K,) each)."""
        while not self._done and (self._t().size == 0 or self._t()[-1] < t_hi_ns):
            self._pull()
        t = self._t()
        first = max(int(np.searchsorted(t, t_lo_ns, side="right")) - 1, 0)
        last = min(int(np.searchsorted(t, t_hi_ns, side="left")) + 1, t.size)
        if self._cols is None:
            return {c: np.zeros(0, np.int64 if c == "t_ns" else np.float64) for c in self._columns}
        return {c: v[first:last] for c, v in self._cols.items()}

    def forget_before(self, t_ns: int) -> None:
        """Let go of the rows before the last one at or before ``t_ns``."""
        if self._cols is None:
            return
        first = max(int(np.searchsorted(self._t(), t_ns, side="right")) - 1, 0)
        if first:
            self._cols = {c: v[first:] for c, v in self._cols.items()}


__all__ = ["BatchTransform", "Columns", "TimeWindow"]

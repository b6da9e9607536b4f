"""A reorder buffer in front of a table writer, so ingested rows reach the disk in time order.

Messages of one table arrive from one or more topics, each roughly in time order but
interleaved with the others chunk by chunk, and a log may hold a late message or two. The
buffer holds about ``buffer_bytes`` of rows; when full it writes, sorted, the rows that no
source can still precede: those up to the *watermark*, the least recent time every source
has reached. Rows arriving behind rows already written are left to the writer, which counts
them and re-sorts its file out of core when it is finished
(:class:`~toolkit.tableio.TableWriter` with ``sort_by="t_ns"``). Memory is bounded by the
buffer whatever the log's length.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from toolkit.tableio import TableWriter

#: Bytes of rows a table holds back to sort them before they are written.
DEFAULT_REORDER_BUFFER_BYTES = 8 * 1024 * 1024

#: Buffered pieces of a table are folded into one once there are this many.
COMPACT_PIECES = 64


def sort_by_time(table: pa.Table) -> pa.Table:
    """``table`` sorted by ``t_ns`` (stable; returned as is when already sorted)."""
    t = table.column("t_ns").to_numpy()
    if len(t) < 2 or bool(np.all(t[1:] >= t[:-1])):
        return table
    return table.take(pc.sort_indices(table, sort_keys=[("t_ns", "ascending")]))


class ReorderBuffer:
    """Rows of one table from several ``sources`` (topics), handed to ``writer`` in time order.

    ``writer`` must have been made with ``sort_by="t_ns"``, so rows later than the buffer
    can hold still end in order. Call :meth:`add` per batch and :meth:`flush` once at the end,
    before finishing the writer.
    """

    def __init__(
        self,
        writer: TableWriter,
        sources: Collection[str],
        *,
        buffer_bytes: int = DEFAULT_REORDER_BUFFER_BYTES,
    ) -> None:
        if writer.sort_by != "t_ns":
            raise ValueError(f"{writer.path}: a reorder buffer needs a writer sorting by t_ns")
        self.writer = writer
        self.buffer_bytes = buffer_bytes
        self._latest: dict[str, int | None] = dict.fromkeys(sources)
        self._pieces: list[pa.Table] = []
        self._bytes = 0

    def add(self, table: pa.Table, source: str, metadata: Mapping[str, str]) -> None:
        """Take rows of one source (any order); ``metadata`` goes to the table's file."""
        self.writer.add_metadata(metadata)
        if table.num_rows == 0:
            return
        newest = int(pc.max(table.column("t_ns")).as_py())
        prev = self._latest.get(source)
        self._latest[source] = newest if prev is None else max(prev, newest)
        self._pieces.append(table)
        self._bytes += table.nbytes
        if self._bytes >= self.buffer_bytes:
            self._write(final=False)
        elif len(self._pieces) >= COMPACT_PIECES:
            # A small table (GPS, heading) may stay buffered for a whole log, arriving as one
            # tiny table per chunk; each piece's own buffers cost far more than its rows, so
            # fold them into one contiguous table to keep memory independent of log length.
            self._pieces = [pa.concat_tables(self._pieces).combine_chunks()]

    def flush(self) -> None:
        """Write everything still buffered."""
        self._write(final=True)

    def _write(self, *, final: bool) -> None:
        if not self._pieces:
            return
        table = sort_by_time(pa.concat_tables(self._pieces))
        t = table.column("t_ns").to_numpy()
        if final:
            n_out = len(t)
        else:
            latest = list(self._latest.values())
            if any(v is None for v in latest):
                n_out = 0  # a source has not spoken yet: it may still precede everything
            else:
                watermark = min(v for v in latest if v is not None)
                n_out = int(np.searchsorted(t, watermark, side="right"))
            held_bytes = table.nbytes * (len(t) - n_out) / max(len(t), 1)
            if held_bytes > 2 * self.buffer_bytes:
                n_out = max(n_out, len(t) // 2)  # a stalled source: keep memory bounded
        out, rest = table.slice(0, n_out), table.slice(n_out)
        if out.num_rows:
            self.writer.write(out)
        self._pieces = [rest] if rest.num_rows else []
        self._bytes = rest.nbytes if rest.num_rows else 0

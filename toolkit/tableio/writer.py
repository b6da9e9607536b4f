"""Writing a table: :class:`TableWriter` streams it aside, checked, then publishes it whole.

Part of :mod:`toolkit.tableio`; the Parquet options every table is written with are here.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from toolkit import fixed_point
from toolkit.atomic import fsync_dir, fsync_file, temp_path_beside
from toolkit.errors import SchemaError, WorkspaceError
from toolkit.tableio.schemas import (
    conform_table,
    contract_metadata,
    from_storage,
    load_table_schema,
    to_storage,
)

#: Rows per Parquet row group at most (big enough for fast scans, small enough to stream).
#: Smaller pieces are gathered up to this many rows before they are written, so a table
#: written in many small pieces still has few row groups: every row group costs its reader
#: ~10 kB of footer metadata held in memory for the whole read (measured on the point cloud
#: with 11 columns: 43 MB for 4,104 row groups), which would grow with the log.
ROW_GROUP_ROWS = 65_536
#: ... or up to this many bytes (a few rows of a wide table, such as the laser scans at
#: ~800 bytes a row, make a row group's worth of memory long before 65,536 rows).
GATHER_BYTES = 8 << 20
#: Rows per row group at most in a bulk table (:class:`TableWriter` ``bulk=True``): the
#: point cloud's pieces (a batch of 2,000 scans, ~340 k points) each become one row group,
#: 700 for an hour of Stanley's five lasers instead of 3,700.
BULK_ROW_GROUP_ROWS = 1_048_576

#: Parquet writer options every table is written with: zstd, and a CRC on every data page so
#: flipped bytes are an error when read (:func:`read_table` verifies them), not values.
PARQUET_OPTIONS: dict[str, Any] = {
    "compression": "zstd",
    "write_page_checksum": True,
    # fixed-point columns (toolkit.fixed_point) as Parquet INT32 decimals, not 16-byte ones
    "store_decimal_as_integer": True,
}


#: What :class:`TableWriter` ``bulk=True`` changes, for a table of hundreds of millions of
#: float rows (the point cloud): floats byte-stream-split (each byte of the values in a run
#: of its own, which zstd compresses far better than whole doubles) and zstd's fast level
#: -5 (still zstd, read by every Parquet reader). Measured on 1.9 M points of a race log:
#: 13.9 M rows/s and 39.0 bytes a point against 10.0 M rows/s and 43.0 with the defaults
#: (level 1, plain floats); writing the cloud is the projection stage's critical path.
BULK_COMPRESSION_LEVEL = -5


def bulk_options(schema: pa.Schema) -> dict[str, Any]:
    """The extra writer options of a bulk table (see :data:`BULK_COMPRESSION_LEVEL`): floats
    byte-stream-split, and the 64-bit integers (times in ns, which rise by small steps from
    row to row) delta-encoded (DELTA_BINARY_PACKED: each value as its difference from the
    one before, bit-packed). On 2.9 M points of a race log the deltas made the cloud 13 %
    smaller (33.9 against 39.1 bytes a point) at the same writing speed (9.4 M rows/s) and
    reading speed (measured); on a 60-minute log (a 9 GB cloud before, 7.8 GB now, where the
    page cache's writeback throttled the writer) the projection went from 3.99 to 4.57 M
    points/s. Both are standard Parquet encodings every reader decodes."""
    encoding = {
        **{f.name: "BYTE_STREAM_SPLIT" for f in schema if pa.types.is_floating(f.type)},
        **{f.name: "DELTA_BINARY_PACKED" for f in schema if pa.types.is_int64(f.type)},
        # fixed-point coordinates: neighbouring beams land centimetres apart, so their
        # whole millimetres differ by small steps (toolkit.fixed_point)
        **{f.name: "DELTA_BINARY_PACKED" for f in schema if fixed_point.is_stored(f.type)},
    }
    return {"compression_level": BULK_COMPRESSION_LEVEL, "column_encoding": encoding}


def dictionary_columns(schema: pa.Schema) -> list[str]:
    """The columns worth dictionary encoding: strings (a laser's topic, a split, a wheel),
    which repeat. Numbers rarely do in these tables (positions, times), and trying a
    dictionary on every float column first made writing the point cloud 3x slower and its
    file 25 % larger (measured on 1 M points: 0.73 s / 55 MB against 0.22 s / 43 MB)."""
    return [
        f.name
        for f in schema
        if pa.types.is_string(f.type)
        or pa.types.is_large_string(f.type)
        or pa.types.is_dictionary(f.type)
    ]


def _concat_pieces(pieces: list[pa.Table]) -> pa.Table:
    """Gathered pieces as one table, their dictionaries unified: a column chunk whose pieces
    carry different dictionaries falls back to plain encoding in Parquet (4x larger,
    measured on a laser column)."""
    return pa.concat_tables(pieces).unify_dictionaries()


class TableWriter:
    """The one way a table reaches the disk: streamed aside, checked, then published whole.

    Rows arrive in pieces (:meth:`write`); each piece is checked against the table schema
    (:func:`conform_table`) and appended to a hidden file beside the destination, as zstd
    Parquet with page checksums, every row group at most :data:`ROW_GROUP_ROWS` rows. The
    contract metadata (:func:`contract_metadata`) is stamped when the file is closed, so
    metadata learnt while streaming (:meth:`add_metadata`) is kept. :meth:`finish` closes the
    file, re-sorts it out of core when ``sort_by`` is given and rows arrived out of order, and
    fsyncs it; :meth:`publish` renames it over the destination and fsyncs the directory.
    :meth:`abort` (or any exception inside ``with``) removes every file the writer made, so
    nothing half-written is ever left behind or seen.

    Use as a context manager for one table (finish and publish on success), or call
    :meth:`finish` on several writers and :meth:`publish` them together once all succeeded.

    ``schema_name`` names a table schema of ``schemas/tables``; ``None`` writes a table that
    has none (e.g. the simulator's ``truth_features``) as given, stamped with ``table_name``
    at version 1. A table that got no rows is written empty with its schema's columns
    (a schema-less one with no row ever written has no columns to write: :meth:`finish`
    then returns False and nothing is published).

    Pieces of fewer than :data:`ROW_GROUP_ROWS` rows (and :data:`GATHER_BYTES`) are gathered
    (checked as they arrive) and written together once they make a row group, or at
    :meth:`finish`; an error writing them is raised there.

    ``bulk``: a table of hundreds of millions of rows whose writing speed matters (the
    point cloud): :func:`bulk_options` on top of the usual ones, and row groups of up to
    :data:`BULK_ROW_GROUP_ROWS` rows. ``statistics``: the columns whose row groups get
    min/max statistics (the ones readers select rows by), or None for every column.
    """

    def __init__(
        self,
        path: str | Path,
        schema_name: str | None,
        *,
        source_sha256: str | Sequence[str],
        config_hash: str,
        extra_metadata: Mapping[str, str] | None = None,
        table_name: str | None = None,
        sort_by: str | None = None,
        bulk: bool = False,
        statistics: Sequence[str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.bulk = bulk
        self._statistics: dict[str, Any] = (
            {} if statistics is None else {"write_statistics": list(statistics)}
        )
        self.schema = load_table_schema(schema_name) if schema_name is not None else None
        if self.schema is None and not table_name:
            raise ValueError("a table without a schema needs a table_name")
        self.table_name = self.schema.name if self.schema is not None else str(table_name)
        self._source_sha256 = source_sha256
        self._config_hash = config_hash
        self._extra: dict[str, str] = dict(extra_metadata or {})
        self.sort_by = sort_by
        self.rows = 0
        #: Rows that arrived before the largest ``sort_by`` value already written.
        self.late_rows = 0
        self.resorted = False
        self._tmp = temp_path_beside(self.path, "partial")
        self._writer: pq.ParquetWriter | None = None
        self._arrow_schema: pa.Schema | None = None
        self._max_key: Any = None
        self._stamped: dict[str, str] = {}
        self._row_group_rows = BULK_ROW_GROUP_ROWS if bulk else ROW_GROUP_ROWS
        #: Checked pieces not yet written (fewer than ROW_GROUP_ROWS rows between them).
        self._gathered: list[pa.Table] = []
        self._gathered_rows = 0
        self._state = "open"  # open -> finished -> published, or -> aborted

    # -- the context manager ---------------------------------------------------------------

    def __enter__(self) -> TableWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        if exc_type is not None:
            self.abort()
            return
        try:
            if self.finish():
                self.publish()
        except BaseException:
            self.abort()
            raise

    # -- writing ---------------------------------------------------------------------------

    def add_metadata(self, metadata: Mapping[str, str]) -> None:
        """Key-value metadata for the file (first value of a key wins)."""
        for key, value in metadata.items():
            self._extra.setdefault(key, value)

    def write(self, table: pa.Table) -> None:
        """Append rows (checked against the schema; extra columns kept after its own)."""
        self._require("open")
        if self.schema is not None:
            table = to_storage(conform_table(table, self.schema, self.path), self.schema, self.path)
        writer = self._writer
        if writer is None:
            writer = self._open(table.schema)
        elif self._arrow_schema is not None and not table.schema.equals(
            self._arrow_schema, check_metadata=False
        ):
            try:
                table = table.cast(self._arrow_schema)
            except (pa.ArrowInvalid, ValueError) as exc:
                raise SchemaError(
                    f"table {self.table_name!r}: a piece whose columns differ from the first "
                    f"({exc})",
                    path=self.path,
                ) from exc
        if table.num_rows == 0:
            return
        self._track_order(table)
        self.rows += table.num_rows
        if (
            self._gathered_rows + table.num_rows < ROW_GROUP_ROWS
            and sum(t.nbytes for t in self._gathered) + table.nbytes < GATHER_BYTES
        ):
            self._gathered.append(table)
            self._gathered_rows += table.num_rows
            return
        if self._gathered:
            table = _concat_pieces([*self._gathered, table])
            self._gathered, self._gathered_rows = [], 0
        self._write_rows(writer, table)

    def _write_rows(self, writer: pq.ParquetWriter, table: pa.Table) -> None:
        try:
            writer.write_table(table, row_group_size=self._row_group_rows)
        except (OSError, pa.ArrowException) as exc:
            raise WorkspaceError(
                f"cannot write table {self.table_name!r}: {exc}", self.path
            ) from exc

    def _track_order(self, table: pa.Table) -> None:
        if self.sort_by is None:
            return
        key = table.column(self.sort_by)
        if self._max_key is not None:
            self.late_rows += int(pc.sum(pc.less(key, self._max_key)).as_py() or 0)
        top = pc.max(key).as_py()
        if top is not None and (self._max_key is None or top > self._max_key):
            self._max_key = top
        if not self._is_sorted(key):
            self.late_rows += 1  # out of order within the piece: the file needs sorting

    @staticmethod
    def _is_sorted(key: pa.ChunkedArray) -> bool:
        values = key.to_numpy()
        return len(values) < 2 or bool((values[1:] >= values[:-1]).all())

    def _open(self, schema: pa.Schema) -> pq.ParquetWriter:
        self._arrow_schema = schema.remove_metadata()
        # The metadata known now goes into the Arrow schema (what every reader shows); keys
        # learnt later are added to the file's key-value metadata when it is closed.
        self._stamped = self._metadata()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(
                self._tmp,
                self._arrow_schema.with_metadata(self._stamped),
                use_dictionary=dictionary_columns(self._arrow_schema),
                **PARQUET_OPTIONS,
                **(bulk_options(self._arrow_schema) if self.bulk else {}),
                **self._statistics,
            )
        except (OSError, pa.ArrowException) as exc:
            raise WorkspaceError(
                f"cannot write table {self.table_name!r}: {exc}", self.path
            ) from exc
        return self._writer

    def _metadata(self) -> dict[str, str]:
        version = self.schema.version if self.schema is not None else 1
        return contract_metadata(
            self.table_name,
            version,
            source_sha256=self._source_sha256,
            config_hash=self._config_hash,
            extra_metadata=self._extra,
        )

    # -- finishing -------------------------------------------------------------------------

    def finish(self) -> bool:
        """Close the hidden file (sorted, fsynced); False when there is nothing to publish."""
        self._require("open")
        try:
            writer = self._writer
            if writer is None:
                if self.schema is None:
                    self._state = "finished"
                    return False
                writer = self._open(to_storage(self.schema.empty_table(), self.schema).schema)
            if self._gathered:
                self._write_rows(writer, _concat_pieces(self._gathered))
                self._gathered, self._gathered_rows = [], 0
            late = {k: v for k, v in self._metadata().items() if k not in self._stamped}
            if late:
                writer.add_key_value_metadata(late)
            self._writer = None
            writer.close()
            if self.sort_by is not None and self.late_rows:
                self._resort(self.sort_by)
            fsync_file(self._tmp)
        except (OSError, pa.ArrowException) as exc:
            raise WorkspaceError(
                f"cannot write table {self.table_name!r}: {exc}", self.path
            ) from exc
        self._state = "finished"
        return True

    def _resort(self, key: str) -> None:
        """Sort the hidden file by ``key`` out of core: polars streams a sorted copy, which is
        written back through pyarrow with the file's own schema and metadata (polars would
        drop the field metadata that carries units)."""
        import polars as pl

        scratch = temp_path_beside(self.path, "sorting")
        final = temp_path_beside(self.path, "partial")
        try:
            pl.scan_parquet(self._tmp).sort(key, maintain_order=True).sink_parquet(
                scratch, compression="zstd", row_group_size=ROW_GROUP_ROWS
            )
            schema = pq.read_schema(self._tmp)
            with pq.ParquetWriter(
                final,
                schema,
                use_dictionary=dictionary_columns(schema),
                **PARQUET_OPTIONS,
                **(bulk_options(schema) if self.bulk else {}),
                **self._statistics,
            ) as writer:
                for batch in pq.ParquetFile(scratch, pre_buffer=False).iter_batches(
                    batch_size=ROW_GROUP_ROWS
                ):
                    writer.write_table(pa.Table.from_batches([batch]).cast(schema))
                late = {k: v for k, v in self._metadata().items() if k not in self._stamped}
                if late:
                    writer.add_key_value_metadata(late)
            self._tmp.unlink()
            self._tmp = final
            self.resorted = True
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                final.unlink()
            raise
        finally:
            with contextlib.suppress(FileNotFoundError):
                scratch.unlink()

    def rewrite(
        self,
        transform: Callable[[pa.Table, int], pa.Table],
        metadata: Mapping[str, str] | None = None,
    ) -> TableWriter:
        """This finished table rewritten, a row group at a time, as
        ``transform(piece, first_row)`` into a new writer for the same destination (returned
        finished, not published); this writer is aborted. The key-value metadata is kept,
        ``metadata`` overriding it. Memory: one row group.
        """
        self._require("finished")
        new = TableWriter(
            self.path,
            self.schema.name if self.schema is not None else None,
            table_name=self.table_name,
            source_sha256=self._source_sha256,
            config_hash=self._config_hash,
            extra_metadata={**self._extra, **(metadata or {})},
        )
        try:
            first = 0
            with pq.ParquetFile(self._tmp, pre_buffer=False) as f:
                for batch in f.iter_batches(batch_size=ROW_GROUP_ROWS):
                    piece = pa.Table.from_batches([batch])
                    if self.schema is not None:
                        piece = from_storage(piece, self.schema)
                    new.write(transform(piece, first))
                    first += piece.num_rows
            new.finish()
        except BaseException:
            new.abort()
            raise
        self.abort()
        return new

    @property
    def finished_path(self) -> Path:
        """The hidden file of a finished, not yet published table (to read it back)."""
        self._require("finished")
        return self._tmp

    def publish(self) -> Path:
        """Rename the finished file over the destination; returns the destination."""
        self._require("finished")
        try:
            os.replace(self._tmp, self.path)
        except OSError as exc:
            raise WorkspaceError(
                f"cannot publish table {self.table_name!r}: {exc}", self.path
            ) from exc
        fsync_dir(self.path.parent)
        self._state = "published"
        return self.path

    def abort(self) -> None:
        """Close and remove everything this writer made (safe to call more than once)."""
        self._gathered, self._gathered_rows = [], 0
        if self._writer is not None:
            with contextlib.suppress(Exception):
                self._writer.close()
            self._writer = None
        if self._state != "published":
            with contextlib.suppress(FileNotFoundError):
                self._tmp.unlink()
            self._state = "aborted"

    def _require(self, state: str) -> None:
        if self._state != state:
            raise WorkspaceError(
                f"table {self.table_name!r}: writer is {self._state}, not {state}", self.path
            )


def write_table(
    path: str | Path,
    table: pa.Table,
    schema_name: str,
    *,
    source_sha256: str | Sequence[str],
    config_hash: str,
    extra_metadata: Mapping[str, str] | None = None,
) -> None:
    """Write a whole table at once through :class:`TableWriter` (checked, atomic).

    ``source_sha256`` is the source log's sha256, or for tables built from several logs a
    sequence of them (stored sorted, comma-separated). ``extra_metadata`` adds key-value
    metadata (e.g. the ENU origin as JSON); it may not override the provenance keys.
    """
    with TableWriter(
        path,
        schema_name,
        source_sha256=source_sha256,
        config_hash=config_hash,
        extra_metadata=extra_metadata,
    ) as writer:
        writer.write(table)

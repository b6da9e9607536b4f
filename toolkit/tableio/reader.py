"""Reading a table: whole, its metadata, its row count, or streamed in batches; each checked
against the table schema it was written for (name, version, columns) and page checksums.

Part of :mod:`toolkit.tableio`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.errors import SchemaError, WorkspaceError
from toolkit.tableio.schemas import (
    META_SCHEMA_NAME,
    META_SCHEMA_VERSION,
    TableSchema,
    from_storage,
    load_table_schema,
)


def _read_schema(path: Path) -> pa.Schema:
    if not path.is_file():
        raise WorkspaceError("no such table file", path=path)
    try:
        return pq.read_schema(path)
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"not a readable Parquet file: {exc}", path=path) from exc


def read_table_metadata(path: str | Path) -> dict[str, str]:
    """The key-value metadata of a Parquet table written by :class:`TableWriter` (the file's,
    which holds the Arrow schema's and any key added when the file was closed)."""
    path = Path(path)
    _read_schema(path)  # a missing or unreadable file is our error, naming it
    try:
        meta = pq.read_metadata(path).metadata or {}
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"not a readable Parquet file: {exc}", path=path) from exc
    return {
        k.decode("utf-8", "replace"): v.decode("utf-8", "replace")
        for k, v in meta.items()
        if k != b"ARROW:schema"
    }


def _check_contract(path: Path, schema: TableSchema) -> None:
    """SchemaError unless ``path`` holds ``schema``'s table at its current version, with every
    one of its columns."""
    meta = read_table_metadata(path)
    found = meta.get(META_SCHEMA_NAME)
    if found != schema.name:
        raise SchemaError(f"holds table {found!r}, expected {schema.name!r}", path=path)
    version = meta.get(META_SCHEMA_VERSION)
    if version != str(schema.version):
        raise SchemaError(
            f"table {schema.name!r} has schema version {version}, this toolkit reads "
            f"version {schema.version}; re-run the stage that writes it",
            path=path,
        )
    names = _read_schema(path).names
    missing = [c for c in schema.column_names if c not in names]
    if missing:
        raise SchemaError(f"table {schema.name!r}, column {missing[0]!r}: missing", path=path)


def read_table(
    path: str | Path, schema_name: str, *, columns: Sequence[str] | None = None
) -> pa.Table:
    """Read a table, checking it was written for ``schema_name`` at the current version.

    A file of another table, or of an older schema version (a stale workspace), is a
    SchemaError; so is a file missing one of the schema's columns, and one whose data pages
    fail their checksums.
    """
    path = Path(path)
    schema = load_table_schema(schema_name)
    _check_contract(path, schema)
    try:
        table = pq.read_table(
            path,
            columns=list(columns) if columns is not None else None,
            page_checksum_verification=True,
        )
        return from_storage(table, schema)
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"cannot read table {schema.name!r}: {exc}", path=path) from exc


def table_num_rows(path: str | Path, schema_name: str) -> int:
    """Rows of a table, from its footer (the contract checked as by :func:`read_table`)."""
    path = Path(path)
    _check_contract(path, load_table_schema(schema_name))
    try:
        return int(pq.ParquetFile(path).metadata.num_rows)
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"cannot read table {schema_name!r}: {exc}", path=path) from exc


def iter_table_batches(
    path: str | Path,
    schema_name: str,
    *,
    columns: Sequence[str],
    batch_rows: int,
    as_dictionary: Sequence[str] = (),
    lean: bool = False,
    row_groups: Sequence[int] | None = None,
) -> Iterator[pa.RecordBatch]:
    """Stream a table in record batches of at most ``batch_rows`` rows (memory bounded by a
    batch), checked as by :func:`read_table`, page checksums verified.

    ``row_groups``: only these row groups (:func:`row_group_ranges` says what each holds),
    in file order; None: all.

    ``as_dictionary``: string columns to read as Arrow dictionary arrays, as the writer
    stored them (:func:`dictionary_columns`), instead of a string per row: for a column of
    five laser names, ~15x faster to read (measured on a points table).

    ``lean``: decode on the calling thread and hand back the memory of the batches consumed
    so far (``MemoryPool.release_unused``) whenever the next is asked for. Arrow's default allocator
    (mimalloc) otherwise keeps pages its decoding threads used: streaming an hour's truth
    pose (365 k rows, 15 MB of values) grew the process by 34 MB, ten minutes' by 14 MB;
    lean, 13 MB both (measured). It costs time on big batches (the point cloud read 7.0 ->
    17.8 s an hour), so it is for the many small batches of a stage's side tables."""
    path = Path(path)
    if lean and as_dictionary:
        raise ValueError("iter_table_batches: lean reading does not regroup dictionary batches")
    schema = load_table_schema(schema_name)
    _check_contract(path, schema)
    try:
        with pq.ParquetFile(
            path,
            page_checksum_verification=True,
            pre_buffer=False,
            read_dictionary=list(as_dictionary) or None,
        ) as f:
            batches = f.iter_batches(
                batch_size=batch_rows,
                row_groups=None if row_groups is None else sorted(set(row_groups)),
                columns=list(columns),
                use_threads=not lean,
            )
            if schema.fixed_point:
                batches = (from_storage(b, schema) for b in batches)
            if lean:
                pool = pa.default_memory_pool()
                for batch in batches:
                    yield batch
                    del batch
                    pool.release_unused()
                return
            if not as_dictionary:
                yield from batches
                return
            # Dictionary batches end at every row group (each has its own dictionary):
            # gathered back to batch_rows, over one dictionary per column.
            group: list[pa.RecordBatch] = []
            rows = 0
            for batch in batches:
                group.append(batch)
                rows += batch.num_rows
                if rows >= batch_rows:
                    yield _one_batch(group)
                    group, rows = [], 0
            if group:
                yield _one_batch(group)
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"cannot read table {schema.name!r}: {exc}", path=path) from exc


def row_group_ranges(
    path: str | Path, schema_name: str, column: str
) -> list[tuple[object, object] | None]:
    """Per row group of a table, the (min, max) of ``column`` its footer's statistics give
    (None where it gives none), checked as by :func:`read_table`: what lets a reader of a
    table written in key order read only the row groups a range of keys can be in."""
    path = Path(path)
    _check_contract(path, load_table_schema(schema_name))
    try:
        meta = pq.ParquetFile(path).metadata
        at = meta.schema.names.index(column)
        out: list[tuple[object, object] | None] = []
        for k in range(meta.num_row_groups):
            stats = meta.row_group(k).column(at).statistics
            ok = stats is not None and stats.has_min_max
            out.append((stats.min, stats.max) if ok else None)
        return out
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise SchemaError(f"cannot read table {schema_name!r}: {exc}", path=path) from exc


def _one_batch(batches: list[pa.RecordBatch]) -> pa.RecordBatch:
    """Record batches of one schema as one batch, their dictionaries unified."""
    if len(batches) == 1:
        return batches[0]
    table = pa.Table.from_batches(batches).unify_dictionaries().combine_chunks()
    return table.to_batches()[0]

"""Versioned table schemas and the one way tables are written to and read from Parquet.

Each table of the contract has a JSON schema in ``schemas/tables/<name>.json`` (shipped as
``toolkit.schemas``): its name, version, and columns with Arrow type, unit, nullability and
description. :func:`write_table` checks a table against its schema before anything touches
the disk (a missing column, a wrong type, a null in a non-null column or a value outside a
column's allowed set is a :class:`~toolkit.errors.SchemaError` naming file, table and
column), then writes zstd-compressed Parquet atomically with the provenance the contract
asks for as key-value metadata. Extra columns are allowed and kept after the schema's.

Type strings in the schema files: ``bool``, ``int8/16/32/64``, ``uint8/16/32/64``,
``float32``, ``float64``, ``string``, ``binary`` and ``list<T>``. Representation variants
(``large_string``, ``large_list``, dictionary-encoded strings, as e.g. polars produces) are
accepted and cast to the schema's type, so every file of one table has the same schema.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.resources
import json
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, TypeVar

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from toolkit import fixed_point
from toolkit.atomic import fsync_dir, fsync_file, temp_path_beside
from toolkit.errors import SchemaError, WorkspaceError

#: Key-value metadata keys every table carries.
META_SCHEMA_NAME = "schema_name"
META_SCHEMA_VERSION = "schema_version"
META_TOOLKIT_VERSION = "toolkit_version"
META_SOURCE_SHA256 = "source_sha256"
META_CONFIG_HASH = "config_hash"
RESERVED_METADATA_KEYS = frozenset(
    {
        META_SCHEMA_NAME,
        META_SCHEMA_VERSION,
        META_TOOLKIT_VERSION,
        META_SOURCE_SHA256,
        META_CONFIG_HASH,
    }
)

_PRIMITIVES: dict[str, pa.DataType] = {
    "bool": pa.bool_(),
    "int8": pa.int8(),
    "int16": pa.int16(),
    "int32": pa.int32(),
    "int64": pa.int64(),
    "uint8": pa.uint8(),
    "uint16": pa.uint16(),
    "uint32": pa.uint32(),
    "uint64": pa.uint64(),
    "float32": pa.float32(),
    "float64": pa.float64(),
    "string": pa.string(),
    "binary": pa.binary(),
}


def parse_arrow_type(text: str) -> pa.DataType:
    """``"list<float32>"`` -> ``pa.list_(pa.float32())``, ``"dictionary<string>"`` ->
    ``pa.dictionary(pa.int32(), pa.string())`` (a column of a few repeated values, stored as
    codes); ValueError on anything unknown."""
    text = text.strip()
    if text in _PRIMITIVES:
        return _PRIMITIVES[text]
    if text.startswith("list<") and text.endswith(">"):
        return pa.list_(parse_arrow_type(text[5:-1]))
    if text.startswith("dictionary<") and text.endswith(">"):  # int32 codes into values
        return pa.dictionary(pa.int32(), parse_arrow_type(text[11:-1]))
    raise ValueError(f"unknown column type {text!r}")


@dataclass(frozen=True)
class ColumnSpec:
    """One column of a table schema."""

    name: str
    type: str
    unit: str
    nullable: bool
    description: str
    values: tuple[str, ...] | None = None
    #: Stored as a fixed-point decimal of this many places (:mod:`toolkit.fixed_point`);
    #: float64 in memory. None: stored as its type says.
    decimal_places: int | None = None

    def arrow_type(self) -> pa.DataType:
        """The column's Arrow type."""
        return parse_arrow_type(self.type)

    def arrow_field(self) -> pa.Field:
        """The Arrow field, carrying unit and description as field metadata."""
        return pa.field(
            self.name,
            self.arrow_type(),
            nullable=self.nullable,
            metadata={"unit": self.unit, "description": self.description},
        )


@dataclass(frozen=True)
class TableSchema:
    """A versioned table schema: the minimum columns a table must have."""

    name: str
    version: int
    description: str
    columns: tuple[ColumnSpec, ...]

    @property
    def column_names(self) -> tuple[str, ...]:
        """Names of the schema's columns, in order."""
        return tuple(c.name for c in self.columns)

    def column(self, name: str) -> ColumnSpec:
        """The spec of one column (KeyError if the schema has none of that name)."""
        for col in self.columns:
            if col.name == name:
                return col
        raise KeyError(name)

    def arrow_schema(self) -> pa.Schema:
        """The Arrow schema of the schema's columns (with units as field metadata)."""
        return pa.schema(
            [c.arrow_field() for c in self.columns],
            metadata={META_SCHEMA_NAME: self.name, META_SCHEMA_VERSION: str(self.version)},
        )

    def empty_table(self) -> pa.Table:
        """A table with the schema's columns and no rows."""
        return self.arrow_schema().empty_table()

    @property
    def fixed_point(self) -> dict[str, int]:
        """The columns stored as fixed-point decimals: name -> decimal places."""
        return {c.name: c.decimal_places for c in self.columns if c.decimal_places is not None}


def _tables_dir() -> Traversable:
    return importlib.resources.files("toolkit.schemas").joinpath("tables")


def table_schema_names() -> list[str]:
    """Names of every packaged table schema, sorted."""
    return sorted(
        p.name[: -len(".json")] for p in _tables_dir().iterdir() if p.name.endswith(".json")
    )


@functools.cache
def load_table_schema(name: str) -> TableSchema:
    """Read ``schemas/tables/<name>.json``; SchemaError if missing or malformed."""
    resource = _tables_dir().joinpath(f"{name}.json")
    where = f"toolkit.schemas/tables/{name}.json"
    try:
        obj = json.loads(resource.read_text(encoding="utf-8"))
    except FileNotFoundError:
        known = ", ".join(table_schema_names())
        raise SchemaError(f"no table schema named {name!r} (known: {known})") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise SchemaError(f"cannot read table schema: {exc}", path=where) from exc
    try:
        columns = tuple(
            ColumnSpec(
                name=str(c["name"]),
                type=str(c["type"]),
                unit=str(c["unit"]),
                nullable=bool(c["nullable"]),
                description=str(c["description"]),
                values=tuple(str(v) for v in c["values"]) if "values" in c else None,
                decimal_places=int(c["decimal_places"]) if "decimal_places" in c else None,
            )
            for c in obj["columns"]
        )
        schema = TableSchema(
            name=str(obj["name"]),
            version=int(obj["version"]),
            description=str(obj.get("description", "")),
            columns=columns,
        )
        for col in columns:
            col.arrow_type()
            if col.decimal_places is not None and (
                col.type != "float64" or not 0 <= col.decimal_places < fixed_point.PRECISION
            ):
                raise ValueError(f"column {col.name!r}: decimal_places needs float64 and 0-8")
    except (KeyError, TypeError, ValueError) as exc:
        raise SchemaError(f"malformed table schema: {exc!r}", path=where) from exc
    if schema.name != name:
        raise SchemaError(f"schema file names itself {schema.name!r}", path=where)
    if len(set(schema.column_names)) != len(columns):
        raise SchemaError("duplicate column names", path=where)
    return schema


# --------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------


def _is_string_view(tp: pa.DataType) -> bool:
    check = getattr(pa.types, "is_string_view", None)  # pyarrow >= 16
    return bool(check(tp)) if check is not None else False


def _compatible(actual: pa.DataType, wanted: pa.DataType) -> bool:
    """Same logical type, possibly in another representation that casts losslessly."""
    if actual.equals(wanted):
        return True
    if pa.types.is_null(actual):
        return True  # an all-null column; the nullability check decides
    if pa.types.is_dictionary(wanted):  # the plain values or codes into them
        plain = actual.value_type if pa.types.is_dictionary(actual) else actual
        return _compatible(plain, wanted.value_type)
    if pa.types.is_dictionary(actual):
        return _compatible(actual.value_type, wanted)
    if pa.types.is_string(wanted):
        return pa.types.is_large_string(actual) or _is_string_view(actual)
    if pa.types.is_list(wanted):
        is_list_like = (
            pa.types.is_list(actual)
            or pa.types.is_large_list(actual)
            or pa.types.is_fixed_size_list(actual)
        )
        return is_list_like and _compatible(actual.value_type, wanted.value_type)
    return False


def conform_table(table: pa.Table, schema: TableSchema, path: str | Path = "") -> pa.Table:
    """Check ``table`` against ``schema`` and return it with the schema's exact types.

    Schema columns come first in schema order (unit and description as field metadata),
    extra columns follow unchanged. Raises SchemaError naming file, table and column.
    """
    where = Path(path) if path else None

    def fail(column: str, problem: str) -> SchemaError:
        return SchemaError(f"table {schema.name!r}, column {column!r}: {problem}", path=where)

    names = table.column_names
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise fail(dupes[0], "appears more than once")
    fields: list[pa.Field] = []
    arrays: list[pa.ChunkedArray] = []
    for col in schema.columns:
        if col.name not in names:
            raise fail(col.name, f"missing (expected {col.type}, {col.unit or 'no unit'})")
        data = table.column(col.name)
        wanted = col.arrow_type()
        if not _compatible(data.type, wanted):
            raise fail(col.name, f"has type {data.type}, expected {col.type}")
        if not data.type.equals(wanted):
            data = data.cast(wanted)
        if not col.nullable and data.null_count:
            raise fail(col.name, f"has {data.null_count} null value(s) but is not nullable")
        if col.values is not None:
            bad = pc.filter(data, pc.invert(pc.is_in(data, value_set=pa.array(col.values))))
            if len(bad) and bad.null_count < len(bad):
                first = next(v for v in bad.to_pylist() if v is not None)
                allowed = ", ".join(repr(v) for v in col.values)
                raise fail(col.name, f"has value {first!r}, expected one of {allowed}")
        fields.append(col.arrow_field())
        arrays.append(data)
    for name in names:
        if name not in schema.column_names:
            fields.append(table.schema.field(name))
            arrays.append(table.column(name))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


# --------------------------------------------------------------------------------------
# Writing and reading
# --------------------------------------------------------------------------------------


_Data = TypeVar("_Data", pa.Table, pa.RecordBatch)


def to_storage(table: pa.Table, schema: TableSchema, path: str | Path = "") -> pa.Table:
    """A conformed table with its fixed-point columns encoded (:func:`fixed_point.encode`);
    SchemaError naming file, table and column on a value the column cannot hold."""
    for name, places in schema.fixed_point.items():
        i = table.schema.get_field_index(name)
        if i < 0 or fixed_point.is_stored(table.schema.field(i).type):
            continue
        try:
            stored = fixed_point.encode(table.column(i), places)
        except fixed_point.FixedPointRangeError as exc:
            raise SchemaError(
                f"table {schema.name!r}, column {name!r}: {exc}", path=Path(path) if path else None
            ) from exc
        table = table.set_column(i, table.schema.field(i).with_type(stored.type), stored)
    return table


def from_storage(data: _Data, schema: TableSchema) -> _Data:
    """``data`` (a table or record batch as read) with its fixed-point columns back to
    float64 (:func:`fixed_point.decode`); other columns as they are."""
    for name in schema.fixed_point:
        i = data.schema.get_field_index(name)
        if i < 0 or not fixed_point.is_stored(data.schema.field(i).type):
            continue
        field = data.schema.field(i).with_type(pa.float64())
        data = data.set_column(i, field, fixed_point.decode(data.column(i)))
    return data


def contract_metadata(
    schema_name: str,
    schema_version: int,
    *,
    source_sha256: str | Sequence[str],
    config_hash: str,
    extra_metadata: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The key-value metadata every table carries (the contract's provenance keys).

    Shared by :func:`write_table` and by writers that stream a table in pieces (ingest), so
    both stamp files the same way. ``extra_metadata`` may not override the provenance keys.
    """
    from toolkit import __version__

    extras = dict(extra_metadata or {})
    clash = RESERVED_METADATA_KEYS & extras.keys()
    if clash:
        raise ValueError(f"extra_metadata may not set {sorted(clash)}")
    bad = [k for k, v in extras.items() if not isinstance(k, str) or not isinstance(v, str)]
    if bad:
        raise ValueError(f"extra_metadata keys and values must be str: {bad}")
    sources = source_sha256 if isinstance(source_sha256, str) else ",".join(sorted(source_sha256))
    return {
        **extras,
        META_SCHEMA_NAME: schema_name,
        META_SCHEMA_VERSION: str(schema_version),
        META_TOOLKIT_VERSION: __version__,
        META_SOURCE_SHA256: sources,
        META_CONFIG_HASH: config_hash,
    }


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
) -> Iterator[pa.RecordBatch]:
    """Stream a table in record batches of at most ``batch_rows`` rows (memory bounded by a
    batch), checked as by :func:`read_table`, page checksums verified.

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
                batch_size=batch_rows, columns=list(columns), use_threads=not lean
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


def _one_batch(batches: list[pa.RecordBatch]) -> pa.RecordBatch:
    """Record batches of one schema as one batch, their dictionaries unified."""
    if len(batches) == 1:
        return batches[0]
    table = pa.Table.from_batches(batches).unify_dictionaries().combine_chunks()
    return table.to_batches()[0]

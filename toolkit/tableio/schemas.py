"""Versioned table schemas: the JSON schema files, checking a table against one, and the
storage form of fixed-point columns and the provenance metadata every table carries.

Part of :mod:`toolkit.tableio`, whose docstring tells the contract.
"""

from __future__ import annotations

import functools
import importlib.resources
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import TypeVar

import pyarrow as pa
import pyarrow.compute as pc

from toolkit import fixed_point
from toolkit.errors import SchemaError

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

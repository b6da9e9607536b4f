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

The package's modules: :mod:`~toolkit.tableio.schemas` (the schema files, checking a
table, storage form and provenance metadata), :mod:`~toolkit.tableio.writer`
(:class:`TableWriter`, :func:`write_table`) and :mod:`~toolkit.tableio.reader`
(:func:`read_table`, :func:`iter_table_batches`, ...). Import from ``toolkit.tableio``.
"""

from toolkit.tableio.reader import (
    iter_table_batches,
    read_table,
    read_table_metadata,
    row_group_ranges,
    table_num_rows,
)
from toolkit.tableio.schemas import (
    META_CONFIG_HASH,
    META_SCHEMA_NAME,
    META_SCHEMA_VERSION,
    META_SOURCE_SHA256,
    META_TOOLKIT_VERSION,
    RESERVED_METADATA_KEYS,
    ColumnSpec,
    TableSchema,
    conform_table,
    contract_metadata,
    from_storage,
    load_table_schema,
    parse_arrow_type,
    table_schema_names,
    to_storage,
)
from toolkit.tableio.writer import (
    BULK_COMPRESSION_LEVEL,
    BULK_ROW_GROUP_ROWS,
    GATHER_BYTES,
    PARQUET_OPTIONS,
    ROW_GROUP_ROWS,
    TableWriter,
    bulk_options,
    dictionary_columns,
    write_table,
)

__all__ = [
    "BULK_COMPRESSION_LEVEL",
    "BULK_ROW_GROUP_ROWS",
    "GATHER_BYTES",
    "META_CONFIG_HASH",
    "META_SCHEMA_NAME",
    "META_SCHEMA_VERSION",
    "META_SOURCE_SHA256",
    "META_TOOLKIT_VERSION",
    "PARQUET_OPTIONS",
    "RESERVED_METADATA_KEYS",
    "ROW_GROUP_ROWS",
    "ColumnSpec",
    "TableSchema",
    "TableWriter",
    "bulk_options",
    "conform_table",
    "contract_metadata",
    "dictionary_columns",
    "from_storage",
    "iter_table_batches",
    "load_table_schema",
    "parse_arrow_type",
    "read_table",
    "read_table_metadata",
    "row_group_ranges",
    "table_num_rows",
    "table_schema_names",
    "to_storage",
    "write_table",
]

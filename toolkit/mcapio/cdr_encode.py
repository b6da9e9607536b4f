"""Encoding a batch of ROS 2 messages, given as columns, into CDR payloads at numpy speed.

The simulator writes hundreds of thousands of messages of a handful of types; encoding them one
by one in Python would dominate its run time. :func:`encode_batch` takes a batch as *columns*
instead (one array per dotted field path: ``"header.stamp.sec"``, ``"ranges"``) and works
column by column:

1. Each column is checked and converted to its wire dtype (:mod:`toolkit.mcapio.cdr_values`);
   a scalar or a single array broadcasts to every message.
2. Messages are grouped by *shape*, the lengths of their strings and sequences (most batches
   have one shape). For each shape :mod:`toolkit.mcapio.cdr_layout` gives the numpy
   structured dtype of a whole payload, CDR padding included.
3. A zeroed structured array of that dtype is filled one column at a time, and its buffer is
   cut into one ``bytes`` payload per message.

Types without a fixed layout (arrays of nested messages or of strings) are encoded one message
at a time by :func:`~toolkit.mcapio.cdr_message.encode_message`, which writes the same bytes
for every other type too and is re-exported here: this module is the encoding entry point.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import NDArray

from toolkit.errors import CdrError
from toolkit.mcapio.cdr_layout import CDR_LE_HEADER, ENCAP, Leaf, Plan, length_name, plan_for
from toolkit.mcapio.cdr_message import Message, encode_message
from toolkit.mcapio.cdr_values import (
    default_value,
    utf8_array,
    wire_array,
    wire_bytes_array,
)

Scalar = bool | int | float | str | bytes | np.generic
#: A column of a batch: one value for every message, or one row per message.
Column = Scalar | NDArray[Any] | Sequence[object] | Mapping[str, object]


@dataclass
class _Prepared:
    """One leaf's column made ready for the structured array.

    ``value`` is the broadcast value (``per_row`` False) or an array indexed by row; ``ragged``
    holds per-row 1-D arrays of a sequence whose length varies; ``length`` is the wire length
    prefix of a string or sequence (an int, or an int array by row).
    """

    value: NDArray[Any] | bytes | None
    per_row: bool
    length: int | NDArray[np.int64] | None = None
    ragged: list[NDArray[Any]] | None = None

    @property
    def rows(self) -> int:
        """Number of rows of a per-row column."""
        if self.ragged is not None:
            return len(self.ragged)
        return 0 if self.value is None else len(self.value)


def encode_batch(
    type_name: str, columns: Mapping[str, Column], n: int | None = None
) -> list[bytes]:
    """Encode a batch of messages given as columns keyed by dotted field path.

    Scalars and strings broadcast to every row; arrays have ``n`` rows first. A fixed array
    (``orientation_covariance``) takes an ``(n, 9)`` array or a ``(9,)`` one to broadcast; a
    sequence (``ranges``) takes an ``(n, len)`` array, a 1-D array to broadcast, or a list of
    ``n`` 1-D arrays whose lengths may differ. Columns left out take the field's default value
    (zero, empty). ``n`` is needed only when every column broadcasts (default 1). A sequence of
    messages (``features``, ``transforms``) takes, per row, a list of dicts or a mapping of
    columns, and makes the type use the slower per-message path.

    Returns ``n`` payloads, CDR header included, in row order.
    """
    plan = plan_for(type_name)
    unknown = sorted(set(columns) - plan.paths)
    if unknown:
        raise CdrError(f"{plan.name} has no field {', '.join(map(repr, unknown))}")
    merged: dict[str, object] = {leaf.path: default_value(leaf) for leaf in plan.leaves}
    merged.update(columns)
    if not plan.has_fixed_layout:
        return _encode_per_message(plan, merged, n)
    prepared = {leaf.path: _prepare(leaf, merged[leaf.path]) for leaf in plan.leaves}
    n = _row_count(plan, prepared, n)
    if n == 0:
        return []
    base: list[int] = []
    varying: list[tuple[int, NDArray[np.int64]]] = []
    for i, leaf in enumerate(plan.dynamic):
        length = prepared[leaf.path].length
        if isinstance(length, np.ndarray):
            varying.append((i, length))
            base.append(0)
        else:
            base.append(int(length or 0))
    if not varying:
        key = tuple(base)
        arr = _fill(plan, prepared, None, key)
        if len(arr) != n:  # every column broadcast: replicate the single row
            arr = np.repeat(arr, n)
        return _split(arr.tobytes(), arr.dtype.itemsize, n)
    matrix = np.stack([lengths for _, lengths in varying], axis=1)
    shapes, inverse = np.unique(matrix, axis=0, return_inverse=True)
    out: list[bytes] = [b""] * n
    for g, shape_row in enumerate(shapes):
        rows = np.flatnonzero(inverse.reshape(-1) == g)
        key_list = list(base)
        for (i, _), v in zip(varying, shape_row, strict=True):
            key_list[i] = int(v)
        arr = _fill(plan, prepared, rows, tuple(key_list))
        payloads = _split(arr.tobytes(), arr.dtype.itemsize, len(rows))
        for r, payload in zip(rows.tolist(), payloads, strict=True):
            out[r] = payload
    return out


# --------------------------------------------------------------------------------------------
# The vectorised path
# --------------------------------------------------------------------------------------------


def _prepare(leaf: Leaf, value: object) -> _Prepared:
    """Check one column and convert it to its wire dtype (step 1)."""
    path = leaf.path
    if leaf.kind in ("scalar", "empty"):
        arr = wire_array(path, leaf, value)
        if arr.ndim == 0:
            return _Prepared(arr, False)
        if arr.ndim != 1:
            raise CdrError(f"field {path!r} is a scalar field, got shape {arr.shape}")
        return _Prepared(arr, True)
    if leaf.kind == "fixed":
        arr = wire_array(path, leaf, value)
        if arr.shape == (leaf.count,):
            return _Prepared(arr, False)
        if arr.ndim != 2 or arr.shape[1] != leaf.count:
            raise CdrError(
                f"field {path!r} is {leaf.type_name}[{leaf.count}], got shape {arr.shape}"
            )
        return _Prepared(arr, True)
    if leaf.kind == "string":
        if isinstance(value, str | bytes):
            raw = value.encode("utf-8") if isinstance(value, str) else value
            return _Prepared(raw, False, len(raw) + 1)
        sarr = utf8_array(path, value)
        if sarr.ndim != 1:
            raise CdrError(f"field {path!r} (string) got shape {sarr.shape}")
        lengths = np.char.str_len(sarr).astype(np.int64) + 1
        if lengths.size and (lengths == lengths[0]).all():
            return _Prepared(sarr, True, int(lengths[0]))
        return _Prepared(sarr, True, lengths)
    return _prepare_sequence(leaf, value)


def _prepare_sequence(leaf: Leaf, value: object) -> _Prepared:
    """A primitive sequence column: one array to broadcast, a 2-D array, or ragged rows."""
    path = leaf.path
    if isinstance(value, np.ndarray) and value.dtype != object:
        arr = wire_array(path, leaf, value)
        if arr.ndim == 1:
            return _Prepared(arr, False, arr.shape[0])
        if arr.ndim == 2:
            return _Prepared(arr, True, arr.shape[1])
        raise CdrError(f"field {path!r} is {leaf.type_name}[], got shape {arr.shape}")
    if isinstance(value, bytes | bytearray):  # one uint8 sequence: broadcast
        arr = wire_bytes_array(path, leaf, value)
        return _Prepared(arr, False, arr.shape[0])
    if not isinstance(value, Sequence | np.ndarray):
        raise CdrError(f"field {path!r} is {leaf.type_name}[], got {type(value).__name__}")
    items = list(value)
    if not items or (np.ndim(items[0]) == 0 and not isinstance(items[0], bytes | bytearray)):
        arr = wire_array(path, leaf, items)  # one sequence given as a list: broadcast
        return _Prepared(arr, False, arr.shape[0])
    ragged = []
    for row in items:
        r = (
            wire_bytes_array(path, leaf, row)
            if isinstance(row, bytes | bytearray)
            else wire_array(path, leaf, row)
        )
        if r.ndim != 1:
            raise CdrError(f"field {path!r}: each row of a sequence must be 1-D, got {r.shape}")
        ragged.append(r)
    lengths = np.fromiter((r.shape[0] for r in ragged), dtype=np.int64, count=len(ragged))
    return _Prepared(None, True, lengths, ragged)


def _row_count(plan: Plan, prepared: Mapping[str, _Prepared], n: int | None) -> int:
    """The batch size: ``n``, else the rows of any per-row column (1 if all broadcast)."""
    counts = {path: prep.rows for path, prep in prepared.items() if prep.per_row}
    if n is None:
        n = next(iter(counts.values()), 1)
    for path, rows in counts.items():
        if rows != n:
            raise CdrError(f"{plan.name}: column {path!r} has {rows} rows, expected {n}")
    return n


def _fill(
    plan: Plan,
    prepared: Mapping[str, _Prepared],
    rows: NDArray[np.intp] | None,
    key: tuple[int, ...],
) -> NDArray[np.void]:
    """The structured array of the rows ``rows`` (None: all rows) sharing shape ``key``."""
    dt = plan.layout(key)
    m = len(rows) if rows is not None else _group_size(prepared)
    out = np.zeros(m, dtype=dt)
    out[ENCAP] = np.frombuffer(CDR_LE_HEADER, dtype=np.uint8)
    lengths = dict(zip((leaf.path for leaf in plan.dynamic), key, strict=True))
    for leaf in plan.leaves:
        prep = prepared[leaf.path]
        if leaf.kind in ("sequence", "string"):
            count = lengths[leaf.path]
            out[length_name(leaf.path)] = count
            if leaf.kind == "string" and count <= 1:
                continue
            if leaf.kind == "sequence" and count == 0:
                continue
        if prep.ragged is not None:
            idx = range(len(prep.ragged)) if rows is None else rows.tolist()
            out[leaf.path] = np.stack([prep.ragged[i] for i in idx])
        elif prep.per_row and rows is not None and isinstance(prep.value, np.ndarray):
            out[leaf.path] = prep.value[rows]
        else:
            out[leaf.path] = prep.value
    return out


def _group_size(prepared: Mapping[str, _Prepared]) -> int:
    """Rows of the first per-row column, else 1 (every column broadcasts)."""
    for prep in prepared.values():
        if prep.per_row:
            return prep.rows
    return 1


def _split(buf: bytes, itemsize: int, count: int) -> list[bytes]:
    """Cut the buffer of a structured array into its ``count`` rows of ``itemsize`` bytes."""
    return [buf[i : i + itemsize] for i in range(0, itemsize * count, itemsize)]


# --------------------------------------------------------------------------------------------
# The per-message path, for types without a fixed layout
# --------------------------------------------------------------------------------------------


#: A column of the per-message path with one entry per row.
_Rows = Sequence[object] | NDArray[Any]


def _encode_per_message(plan: Plan, merged: Mapping[str, object], n: int | None) -> list[bytes]:
    """Cut the columns into one message dict per row and encode each with encode_message."""
    per_row: dict[str, _Rows] = {}
    broadcast: dict[str, object] = {}
    for leaf in plan.leaves:
        if leaf.kind == "empty":
            continue
        value = merged[leaf.path]
        rows = _rows_of(leaf, value)
        if rows is None:
            broadcast[leaf.path] = value
        else:
            if n is not None and len(rows) != n:
                raise CdrError(
                    f"{plan.name}: column {leaf.path!r} has {len(rows)} rows, expected {n}"
                )
            n = len(rows)
            per_row[leaf.path] = rows
    complex_paths = {leaf.path for leaf in plan.leaves if leaf.kind == "complex"}
    out = []
    for i in range(1 if n is None else n):
        msg: dict[str, object] = dict(broadcast)
        for path, rows in per_row.items():
            msg[path] = _element_rows(rows[i]) if path in complex_paths else rows[i]
        out.append(encode_message(plan.spec, msg))
    return out


def _rows_of(leaf: Leaf, value: object) -> _Rows | None:
    """The rows of a per-row column, or None for a value that broadcasts to every row.

    A scalar or string field is per row if 1-D, a fixed array or sequence if 2-D (a list of
    1-D rows for a sequence); an array of messages or strings always has one entry per row.
    """
    if leaf.kind == "complex":
        if value is None:
            return None
        if _is_rows(value):
            return value
        raise CdrError(f"field {leaf.path!r} is an array, got {type(value).__name__}")
    if isinstance(value, str | bytes):
        return None
    if leaf.kind != "sequence" or isinstance(value, np.ndarray) and value.dtype != object:
        arr = np.asarray(value)
        per_row_ndim = 1 if leaf.kind in ("scalar", "string") else 2
        return arr if arr.ndim == per_row_ndim else None
    if not isinstance(value, Sequence | np.ndarray):
        raise CdrError(f"field {leaf.path!r} is {leaf.type_name}[], got {type(value).__name__}")
    if len(value) == 0 or np.ndim(value[0]) == 0:
        return None  # one sequence given as a list: broadcast
    return value


def _is_rows(value: object) -> TypeGuard[_Rows]:
    """Whether ``value`` holds one entry per row: an array of 1 or more dimensions, a list."""
    if isinstance(value, np.ndarray):
        return value.ndim > 0
    return isinstance(value, Sequence) and not isinstance(value, str | bytes)


def _element_rows(row: object) -> object:
    """One message's array of messages: a list of dicts, or a mapping of element columns."""
    if isinstance(row, Mapping):
        return _columns_to_dicts(row)
    return row


def _columns_to_dicts(columns: Mapping[str, object]) -> list[Message]:
    """A mapping of columns (one row per element) -> a list of flat dicts, one per element."""
    per_row = {key: value for key, value in columns.items() if _is_rows(value)}
    lengths = {len(v) for v in per_row.values()}
    if len(lengths) > 1:
        raise CdrError(f"element columns have different lengths: {sorted(lengths)}")
    k = lengths.pop() if lengths else 0
    return [
        {key: (per_row[key][j] if key in per_row else col) for key, col in columns.items()}
        for j in range(k)
    ]


__all__ = ["Column", "Scalar", "encode_batch", "encode_message"]

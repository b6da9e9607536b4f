"""Vectorised CDR encoding and decoding of ROS 2 messages, a whole batch at a time.

ROS 2 serialises messages as XCDR1 little-endian: a 4-byte encapsulation header ``00 01 00 00``,
then the fields in order, each primitive aligned to its own size counted from the end of the
header; a string is a uint32 length (bytes including the NUL) then the bytes and a NUL; a sequence
is a uint32 element count then the elements.

Once the length of every string and sequence in a message is known (its *shape*), every field
sits at a fixed offset, so a batch of messages sharing a shape is one numpy structured array.
:func:`encode_batch` fills such an array column by column and slices its buffer into one
payload per message; :func:`decode_batch` joins same-shaped payloads and views them through the
same dtype. Neither does Python work per field per message, which is what makes ingesting a
chunk of thousands of laser scans take milliseconds.

Messages holding sequences of nested messages or arrays of strings (``tf2_msgs/TFMessage``,
``terrain_msgs/RoughFeatureArray``) have no fixed layout; they take a slower per-message path
built on ``mcap_ros2``'s reference serialiser and decoder. :func:`encode_message` is that
reference path for a single message.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from types import SimpleNamespace
from typing import Any

import numpy as np
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from toolkit.errors import CdrError, SchemaError
from toolkit.mcapio.msgdefs import (
    FieldSpec,
    MessageSpec,
    full_type_name,
    load_msgdef,
    parse_msgdef,
    parse_schema_text,
)

#: Encapsulation header of little-endian plain CDR (XCDR1), as ROS 2 writes it.
CDR_LE_HEADER = b"\x00\x01\x00\x00"

#: Wire types of ROS 2 primitives (little-endian). ``char`` is uint8 in ROS 2.
PRIMITIVE_DTYPES: dict[str, np.dtype[Any]] = {
    "bool": np.dtype("u1"),
    "byte": np.dtype("u1"),
    "char": np.dtype("u1"),
    "uint8": np.dtype("u1"),
    "int8": np.dtype("i1"),
    "int16": np.dtype("<i2"),
    "uint16": np.dtype("<u2"),
    "int32": np.dtype("<i4"),
    "uint32": np.dtype("<u4"),
    "int64": np.dtype("<i8"),
    "uint64": np.dtype("<u8"),
    "float32": np.dtype("<f4"),
    "float64": np.dtype("<f8"),
}

_ENCAP = "#encap"
_U32 = struct.Struct("<I")
#: Most trailing bytes tolerated after the last field (some DDS layers pad to a multiple of 4).
_MAX_TRAILING = 7
#: Shapes guessed and checked in bulk by decode_batch before it reads payloads one by one.
_GUESS_ROUNDS = 4

Scalar = bool | int | float | str | np.generic
Column = Scalar | np.ndarray | Sequence[Any] | Mapping[str, Any]


# --------------------------------------------------------------------------------------------
# Flattening a message spec into leaves
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Leaf:
    """One wire-level field of a flattened message.

    ``kind`` is ``scalar``, ``fixed`` (fixed-size primitive array), ``sequence`` (primitive
    sequence), ``string``, ``empty`` (the placeholder byte of a field-less message) or
    ``complex`` (an array of messages or strings: no fixed layout).
    """

    path: str
    kind: str
    type_name: str
    dtype: np.dtype[Any] | None = None
    count: int = 1
    spec: FieldSpec | None = None

    @property
    def size(self) -> int:
        return 1 if self.dtype is None else self.dtype.itemsize

    @property
    def is_bool(self) -> bool:
        return self.type_name == "bool"


def _flatten(spec: MessageSpec, prefix: str = "") -> list[_Leaf]:
    leaves: list[_Leaf] = []
    if not spec.fields:
        # ROS 2 gives a field-less message one uint8 so that it is not empty on the wire.
        leaves.append(_Leaf(f"{prefix}#empty", "empty", "uint8", PRIMITIVE_DTYPES["uint8"]))
        return leaves
    for f in spec.fields:
        path = f"{prefix}{f.name}"
        if f.type_name == "wstring":
            raise SchemaError(f"{spec.name}.{f.name}: wstring fields are not supported")
        if f.nested is not None:
            if f.is_array:
                leaves.append(_Leaf(path, "complex", f.type_name, spec=f))
            else:
                leaves.extend(_flatten(f.nested, f"{path}."))
        elif f.is_string:
            kind = "complex" if f.is_array else "string"
            leaves.append(_Leaf(path, kind, f.type_name, spec=f))
        else:
            dt = PRIMITIVE_DTYPES[f.type_name]
            if not f.is_array:
                leaves.append(_Leaf(path, "scalar", f.type_name, dt, spec=f))
            elif f.array_length is not None:
                leaves.append(_Leaf(path, "fixed", f.type_name, dt, f.array_length, spec=f))
            else:
                leaves.append(_Leaf(path, "sequence", f.type_name, dt, spec=f))
    return leaves


def _align(offset: int, size: int) -> int:
    """Align an absolute payload offset; alignment counts from the end of the 4-byte header."""
    rel = offset - 4
    return 4 + (rel + size - 1) // size * size if size > 1 else offset


@dataclass
class _Plan:
    """Everything about a message type that does not depend on one batch's shape."""

    spec: MessageSpec
    leaves: tuple[_Leaf, ...]
    dynamic: tuple[_Leaf, ...]
    complex: bool
    layouts: dict[tuple[tuple[int, ...], int], np.dtype[Any]] = field(default_factory=dict)

    @property
    def paths(self) -> frozenset[str]:
        return frozenset(leaf.path for leaf in self.leaves if leaf.kind != "empty")

    def shape_key(self, shape: Mapping[str, int]) -> tuple[int, ...]:
        try:
            key = tuple(int(shape[leaf.path]) for leaf in self.dynamic)
        except KeyError as exc:
            raise CdrError(f"{self.spec.name}: shape lacks the length of {exc.args[0]!r}") from exc
        if any(v < 0 or v > 0xFFFFFFFF for v in key):
            raise CdrError(f"{self.spec.name}: shape lengths must fit in a uint32: {dict(shape)}")
        return key

    def layout(self, key: tuple[int, ...], itemsize: int | None = None) -> np.dtype[Any]:
        """The structured dtype of one payload of shape ``key`` (cached)."""
        cache_key = (key, -1 if itemsize is None else itemsize)
        dt = self.layouts.get(cache_key)
        if dt is None:
            dt = self._build_layout(key, itemsize)
            self.layouts[cache_key] = dt
        return dt

    def _build_layout(self, key: tuple[int, ...], itemsize: int | None) -> np.dtype[Any]:
        if self.complex:
            raise CdrError(f"{self.spec.name} has no fixed layout (it holds arrays of messages)")
        names: list[str] = [_ENCAP]
        formats: list[Any] = [(np.dtype("u1"), (4,))]
        offsets: list[int] = [0]
        lengths = dict(zip((leaf.path for leaf in self.dynamic), key, strict=True))
        off = 4

        def add(name: str, fmt: Any, at: int) -> None:
            names.append(name)
            formats.append(fmt)
            offsets.append(at)

        for leaf in self.leaves:
            if leaf.kind in ("scalar", "empty"):
                off = _align(off, leaf.size)
                add(leaf.path, leaf.dtype, off)
                off += leaf.size
            elif leaf.kind == "fixed":
                off = _align(off, leaf.size)
                add(leaf.path, (leaf.dtype, (leaf.count,)), off)
                off += leaf.size * leaf.count
            elif leaf.kind == "sequence":
                off = _align(off, 4)
                add(f"{leaf.path}#n", np.dtype("<u4"), off)
                off += 4
                count = lengths[leaf.path]
                if count:
                    off = _align(off, leaf.size)
                    add(leaf.path, (leaf.dtype, (count,)), off)
                    off += leaf.size * count
            elif leaf.kind == "string":
                off = _align(off, 4)
                add(f"{leaf.path}#n", np.dtype("<u4"), off)
                off += 4
                nbytes = lengths[leaf.path]
                if nbytes > 1:
                    add(leaf.path, np.dtype(f"S{nbytes - 1}"), off)
                if nbytes > 0:
                    add(f"{leaf.path}#nul", np.dtype("u1"), off + nbytes - 1)
                off += nbytes
        size = off if itemsize is None else itemsize
        if size < off:
            raise CdrError(f"{self.spec.name}: itemsize {size} is shorter than the layout ({off})")
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})

    def walk(self, data: bytes, index: int) -> tuple[tuple[int, ...], int]:
        """Read one payload's length prefixes: its shape key and the end of its last field."""
        _check_header(self.spec.name, data, index)
        n = len(data)
        off = 4
        key: list[int] = []
        for leaf in self.leaves:
            if leaf.kind in ("scalar", "empty"):
                off = _align(off, leaf.size) + leaf.size
            elif leaf.kind == "fixed":
                off = _align(off, leaf.size) + leaf.size * leaf.count
            else:  # sequence or string: read the uint32 prefix
                off = _align(off, 4)
                if off + 4 > n:
                    raise _truncated(self.spec.name, index, leaf.path, off + 4, n)
                count = _U32.unpack_from(data, off)[0]
                off += 4
                key.append(count)
                if count:
                    off = _align(off, leaf.size) + leaf.size * count
            if off > n:
                raise _truncated(self.spec.name, index, leaf.path, off, n)
        return tuple(key), off


def _truncated(type_name: str, index: int, path: str, need: int, have: int) -> CdrError:
    return CdrError(
        f"{type_name}: payload {index} is truncated in field {path!r} "
        f"(needs at least {need} bytes, has {have})"
    )


def _check_header(type_name: str, data: bytes, index: int) -> None:
    if len(data) < 4:
        raise CdrError(f"{type_name}: payload {index} has {len(data)} bytes, no CDR header")
    if data[0] != 0 or data[1] != 1:
        raise CdrError(
            f"{type_name}: payload {index} has encapsulation {data[:2].hex()}, "
            "only little-endian plain CDR (0001) is supported"
        )


@lru_cache(maxsize=256)
def _plan_for_spec(spec: MessageSpec) -> _Plan:
    leaves = tuple(_flatten(spec))
    dynamic = tuple(leaf for leaf in leaves if leaf.kind in ("sequence", "string"))
    complex_ = any(leaf.kind == "complex" for leaf in leaves)
    return _Plan(spec, leaves, dynamic, complex_)


@lru_cache(maxsize=256)
def _plan_for_name(type_name: str) -> _Plan:
    return _plan_for_spec(parse_msgdef(type_name))


def _resolve(type_name: str | MessageSpec, schema_text: str | None = None) -> _Plan:
    if isinstance(type_name, MessageSpec):
        return _plan_for_spec(type_name)
    if schema_text is not None:
        return _plan_for_spec(parse_schema_text(type_name, schema_text))
    return _plan_for_name(full_type_name(type_name))


def layout(spec: MessageSpec, shape: Mapping[str, int]) -> np.dtype[Any]:
    """The numpy structured dtype covering a whole payload of ``spec`` with the given shape.

    ``shape`` maps the dotted path of every string and sequence field (``"header.frame_id"``,
    ``"ranges"``) to its uint32 length prefix as it appears on the wire: the element count of a
    sequence, the byte count *including the NUL* of a string. The dtype starts with the 4-byte
    encapsulation header (``"#encap"``), names each field by its dotted path, each length prefix
    ``"<path>#n"`` and each string terminator ``"<path>#nul"``, and leaves alignment padding
    unnamed. Its itemsize is the exact payload length.
    """
    plan = _plan_for_spec(spec)
    return plan.layout(plan.shape_key(shape))


# --------------------------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------------------------


@dataclass
class _Prepared:
    """One leaf's column made ready for the structured array.

    ``value`` is the broadcast value (``per_row`` False) or an array indexed by row; ``ragged``
    holds per-row 1-D arrays of a sequence whose length varies; ``length`` is the wire length
    prefix (an int, or an int array by row).
    """

    value: Any
    per_row: bool
    length: int | np.ndarray | None = None
    ragged: list[np.ndarray] | None = None


def _numeric(path: str, leaf: _Leaf, value: Any) -> np.ndarray:
    """``value`` as an array of the leaf's wire dtype, refusing lossy or out-of-range input."""
    assert leaf.dtype is not None  # leaves of numeric kinds always carry a dtype
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise CdrError(f"field {path!r}: cannot make an array of {type(value).__name__}") from exc
    target = leaf.dtype
    if arr.size == 0 and arr.dtype.kind in "biufO":
        return np.zeros(arr.shape, dtype=target)
    if arr.dtype.kind not in "biuf":
        raise CdrError(f"field {path!r} ({leaf.type_name}) got non-numeric values ({arr.dtype})")
    if target.kind in "iu" and not leaf.is_bool:
        if arr.dtype.kind == "f":
            raise CdrError(f"field {path!r} ({leaf.type_name}) got floating-point values")
        if arr.size:
            info = np.iinfo(target)
            lo, hi = arr.min(), arr.max()
            if lo < info.min or hi > info.max:
                raise CdrError(
                    f"field {path!r} ({leaf.type_name}) value out of range: [{lo}, {hi}]"
                )
    elif leaf.is_bool:
        if arr.dtype.kind == "f":
            raise CdrError(f"field {path!r} (bool) got floating-point values")
        arr = arr != 0
    return arr.astype(target, copy=False)


def _encode_strings(path: str, value: Any) -> np.ndarray:
    """A 1-D array of str -> a bytes (``S``) array of their UTF-8 encodings."""
    arr = np.asarray(value)
    if arr.dtype.kind == "S":
        return arr
    if arr.dtype.kind not in "UO":
        raise CdrError(f"field {path!r} (string) got {arr.dtype} values")
    if arr.dtype.kind == "U":
        try:
            return arr.astype("S")
        except UnicodeEncodeError:
            pass
    try:
        return np.array([str(s).encode("utf-8") for s in arr.tolist()], dtype="S")
    except (TypeError, UnicodeEncodeError) as exc:
        raise CdrError(f"field {path!r} (string): {exc}") from exc


def _prepare(leaf: _Leaf, value: Any) -> _Prepared:
    path = leaf.path
    if leaf.kind in ("scalar", "empty"):
        arr = _numeric(path, leaf, value)
        if arr.ndim == 0:
            return _Prepared(arr, False)
        if arr.ndim != 1:
            raise CdrError(f"field {path!r} is a scalar field, got shape {arr.shape}")
        return _Prepared(arr, True)
    if leaf.kind == "fixed":
        arr = _numeric(path, leaf, value)
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
        sarr = _encode_strings(path, value)
        if sarr.ndim != 1:
            raise CdrError(f"field {path!r} (string) got shape {sarr.shape}")
        lengths = np.char.str_len(sarr).astype(np.int64) + 1
        if lengths.size and (lengths == lengths[0]).all():
            return _Prepared(sarr, True, int(lengths[0]))
        return _Prepared(sarr, True, lengths)
    # primitive sequence
    if isinstance(value, np.ndarray) and value.dtype != object:
        arr = _numeric(path, leaf, value)
        if arr.ndim == 1:
            return _Prepared(arr, False, arr.shape[0])
        if arr.ndim == 2:
            return _Prepared(arr, True, arr.shape[1])
        raise CdrError(f"field {path!r} is {leaf.type_name}[], got shape {arr.shape}")
    if isinstance(value, bytes | bytearray):  # one uint8 sequence: broadcast
        arr = _numeric(path, leaf, np.frombuffer(value, dtype=np.uint8))
        return _Prepared(arr, False, arr.shape[0])
    items = list(value)
    if not items or (np.ndim(items[0]) == 0 and not isinstance(items[0], bytes | bytearray)):
        arr = _numeric(path, leaf, items)  # one sequence given as a list: broadcast
        return _Prepared(arr, False, arr.shape[0])
    ragged = []
    for row in items:
        if isinstance(row, bytes | bytearray):
            row = np.frombuffer(row, dtype=np.uint8)
        r = _numeric(path, leaf, row)
        if r.ndim != 1:
            raise CdrError(f"field {path!r}: each row of a sequence must be 1-D, got {r.shape}")
        ragged.append(r)
    lengths = np.fromiter((r.shape[0] for r in ragged), dtype=np.int64, count=len(ragged))
    return _Prepared(None, True, lengths, ragged)


def _row_count(plan: _Plan, prepared: Mapping[str, _Prepared], n: int | None) -> int:
    counts: dict[str, int] = {}
    for path, prep in prepared.items():
        if prep.per_row:
            counts[path] = len(prep.ragged) if prep.ragged is not None else len(prep.value)
    if n is None:
        n = next(iter(counts.values()), 1)
    for path, rows in counts.items():
        if rows != n:
            raise CdrError(f"{plan.spec.name}: column {path!r} has {rows} rows, expected {n}")
    return n


def _defaults(plan: _Plan) -> dict[str, Any]:
    """Values of columns the caller leaves out: the field's declared default, else zero/empty."""
    out: dict[str, Any] = {}
    for leaf in plan.leaves:
        f = leaf.spec
        default = f.default if f is not None else None
        if leaf.kind in ("scalar", "empty"):
            out[leaf.path] = 0 if default is None else default
        elif leaf.kind == "fixed":
            out[leaf.path] = np.zeros(leaf.count) if default is None else np.asarray(default)
        elif leaf.kind == "string":
            out[leaf.path] = "" if default is None else str(default)
        elif leaf.kind == "sequence":
            out[leaf.path] = np.zeros(0) if default is None else np.asarray(default)
        else:
            out[leaf.path] = None
    return out


def _fill(
    plan: _Plan,
    prepared: Mapping[str, _Prepared],
    rows: np.ndarray | None,
    key: tuple[int, ...],
) -> np.ndarray:
    """Build the structured array of the rows ``rows`` (None: all rows) sharing shape ``key``."""
    dt = plan.layout(key)
    m = _group_size(prepared, rows)
    out = np.zeros(m, dtype=dt)
    out[_ENCAP] = np.frombuffer(CDR_LE_HEADER, dtype=np.uint8)
    lengths = dict(zip((leaf.path for leaf in plan.dynamic), key, strict=True))
    for leaf in plan.leaves:
        prep = prepared[leaf.path]
        if leaf.kind in ("sequence", "string"):
            count = lengths[leaf.path]
            out[f"{leaf.path}#n"] = count
            if leaf.kind == "string" and count <= 1:
                continue
            if leaf.kind == "sequence" and count == 0:
                continue
        if prep.ragged is not None:
            idx = range(len(prep.ragged)) if rows is None else rows.tolist()
            out[leaf.path] = np.stack([prep.ragged[i] for i in idx])
        elif prep.per_row and rows is not None:
            out[leaf.path] = prep.value[rows]
        else:
            out[leaf.path] = prep.value
    return out


def _group_size(prepared: Mapping[str, _Prepared], rows: np.ndarray | None) -> int:
    if rows is not None:
        return len(rows)
    for prep in prepared.values():
        if prep.per_row:
            return len(prep.ragged) if prep.ragged is not None else len(prep.value)
    return 1


def _split(buf: bytes, itemsize: int, count: int) -> list[bytes]:
    return [buf[i : i + itemsize] for i in range(0, itemsize * count, itemsize)]


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
    columns, and makes the type use the slower reference path.
    """
    plan = _resolve(type_name)
    unknown = sorted(set(columns) - plan.paths)
    if unknown:
        raise CdrError(f"{plan.spec.name} has no field {', '.join(map(repr, unknown))}")
    merged = {**_defaults(plan), **columns}
    if plan.complex:
        return _encode_slow(plan, merged, n)
    prepared = {leaf.path: _prepare(leaf, merged[leaf.path]) for leaf in plan.leaves}
    n = _row_count(plan, prepared, n)
    if n == 0:
        return []
    base: list[int] = []
    varying: list[tuple[int, np.ndarray]] = []
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
# Reference (slow) path
# --------------------------------------------------------------------------------------------


def _to_reference(value: Any) -> Any:
    """Turn numpy values into what ``mcap_ros2``'s serialiser accepts (lists, bytes, dicts)."""
    if isinstance(value, np.ndarray):
        if value.dtype == np.uint8:
            return value.tobytes()
        return (
            [_to_reference(v) for v in value.tolist()]
            if value.dtype == object
            else (value.tolist())
        )
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {k: _to_reference(v) for k, v in _unflatten(value).items()}
    if isinstance(value, list | tuple):
        return [_to_reference(v) for v in value]
    return value


def _unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1, "c": 2}`` -> ``{"a": {"b": 1}, "c": 2}``; nested dicts are copied, not
    modified, and merge with dotted keys under the same prefix."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        parts = key.split(".")
        node = out
        for part in parts[:-1]:
            child = node.get(part, {})
            if not isinstance(child, Mapping):
                raise CdrError(f"field {key!r} conflicts with the value given for {part!r}")
            node[part] = child = dict(child)
            node = child
        last = parts[-1]
        if isinstance(value, Mapping) and isinstance(node.get(last), Mapping):
            node[last] = {**node[last], **value}
        else:
            node[last] = value
    return out


@lru_cache(maxsize=64)
def _reference_encoder(type_name: str) -> Any:
    name = full_type_name(type_name)
    return serialize_dynamic(name, load_msgdef(name))[name]


@lru_cache(maxsize=64)
def _reference_decoder(type_name: str, schema_text: str | None) -> Any:
    name = full_type_name(type_name)
    text = load_msgdef(name) if schema_text is None else schema_text
    try:
        return generate_dynamic(name, text)[name]
    except Exception as exc:  # the reference parser raises assorted exception types
        raise SchemaError(f"cannot build a decoder for {name}: {exc}") from exc


def encode_message(type_name: str, msg: Mapping[str, Any]) -> bytes:
    """Encode one message with ``mcap_ros2``'s reference serialiser (the slow, trusted path).

    ``msg`` is a nested dict (``{"header": {"stamp": {"sec": 1}}}``) or a dict of dotted paths;
    numpy arrays and scalars are accepted. Missing fields take their defaults.
    """
    encoder = _reference_encoder(full_type_name(type_name))
    try:
        return bytes(encoder(_to_reference(msg)))
    except (ValueError, TypeError, struct.error, OverflowError) as exc:
        raise CdrError(f"{full_type_name(type_name)}: cannot encode message: {exc}") from exc


def _slow_column(leaf: _Leaf, value: Any) -> tuple[bool, Any]:
    """A column for the slow path: (per_row, value); per-row values are indexable by row."""
    if leaf.kind == "complex":
        return (False, []) if value is None else (True, list(value))
    if isinstance(value, str | bytes):
        return False, value
    if isinstance(value, np.ndarray) and value.dtype != object or leaf.kind != "sequence":
        arr = np.asarray(value)
        per_row_ndim = 1 if leaf.kind in ("scalar", "string", "empty") else 2
        return arr.ndim == per_row_ndim, arr
    items = list(value)
    if not items or np.ndim(items[0]) == 0:
        return False, items
    return True, items


def _element_rows(row: Any) -> list[Any]:
    """One message's array of messages: a list of dicts, or a mapping of element columns."""
    if isinstance(row, Mapping):
        return _columns_to_dicts(row)
    return list(row)


def _columns_to_dicts(columns: Mapping[str, Any]) -> list[dict[str, Any]]:
    """A mapping of columns (one row per element) -> a list of flat dicts, one per element."""
    per_row = {
        k: v for k, v in columns.items() if not isinstance(v, str | bytes) and np.ndim(v) > 0
    }
    lengths = {len(v) for v in per_row.values()}
    if len(lengths) > 1:
        raise CdrError(f"element columns have different lengths: {sorted(lengths)}")
    k = lengths.pop() if lengths else 0
    return [
        {key: (col[j] if key in per_row else col) for key, col in columns.items()} for j in range(k)
    ]


def _encode_slow(plan: _Plan, merged: Mapping[str, Any], n: int | None) -> list[bytes]:
    columns = {
        leaf.path: _slow_column(leaf, merged[leaf.path])
        for leaf in plan.leaves
        if leaf.kind != "empty"
    }
    rows = n
    for path, (per_row, value) in columns.items():
        if per_row:
            if rows is not None and rows != len(value):
                raise CdrError(
                    f"{plan.spec.name}: column {path!r} has {len(value)} rows, expected {rows}"
                )
            rows = len(value)
    rows = 1 if rows is None else rows
    kinds = {leaf.path: leaf.kind for leaf in plan.leaves}
    out = []
    for i in range(rows):
        msg: dict[str, Any] = {}
        for path, (per_row, value) in columns.items():
            v = value[i] if per_row else value
            msg[path] = _element_rows(v) if kinds[path] == "complex" else v
        out.append(encode_message(plan.spec.name, msg))
    return out


def _objects_to_columns(spec: MessageSpec, objs: Sequence[Any]) -> dict[str, Any]:
    """Reference-decoded messages -> columns keyed by dotted path (nested arrays recurse)."""
    plan = _plan_for_spec(spec)
    out: dict[str, Any] = {}
    for leaf in plan.leaves:
        if leaf.kind == "empty":
            continue
        parts = leaf.path.split(".")
        values = []
        for obj in objs:
            v = obj
            for p in parts:
                v = getattr(v, p)
            values.append(v)
        if leaf.kind == "complex":
            f = leaf.spec
            assert f is not None
            col = np.empty(len(values), dtype=object)
            for i, v in enumerate(values):
                if f.nested is not None:
                    col[i] = _objects_to_columns(f.nested, v)
                else:
                    col[i] = np.array(list(v), dtype=str)
            out[leaf.path] = col
        elif leaf.kind == "string":
            out[leaf.path] = np.array(values, dtype=str)
        elif leaf.kind == "scalar":
            assert leaf.dtype is not None
            out[leaf.path] = np.array(values, dtype=_native(leaf))
        else:
            rows = [
                np.frombuffer(v, np.uint8) if isinstance(v, bytes) else np.asarray(v)
                for v in values
            ]
            out[leaf.path] = _stack_rows(rows, _native(leaf))
    return out


def _stack_rows(rows: Sequence[np.ndarray], dtype: np.dtype[Any]) -> np.ndarray:
    """Equal-length rows -> a 2-D array; otherwise an object array of 1-D arrays."""
    if len({len(r) for r in rows}) <= 1:
        if not rows:
            return np.zeros((0, 0), dtype=dtype)
        return np.stack([np.asarray(r, dtype=dtype) for r in rows])
    col = np.empty(len(rows), dtype=object)
    for i, r in enumerate(rows):
        col[i] = np.asarray(r, dtype=dtype)
    return col


def _native(leaf: _Leaf) -> np.dtype[Any]:
    if leaf.is_bool:
        return np.dtype(bool)
    assert leaf.dtype is not None
    return leaf.dtype.newbyteorder("=")


def _decode_slow(plan: _Plan, payloads: Sequence[bytes], schema_text: str | None) -> dict[str, Any]:
    decoder = _reference_decoder(plan.spec.name, schema_text)
    objs: list[SimpleNamespace] = []
    for i, data in enumerate(payloads):
        _check_header(plan.spec.name, data, i)
        try:
            objs.append(decoder(data))
        except Exception as exc:  # struct.error, IndexError, UnicodeDecodeError...
            raise CdrError(f"{plan.spec.name}: payload {i} cannot be decoded: {exc!r}") from exc
    return _objects_to_columns(plan.spec, objs)


# --------------------------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------------------------


def _check_group(plan: _Plan, arr: np.ndarray, key: tuple[int, ...]) -> np.ndarray:
    """Rows of a candidate group whose header and length prefixes match ``key``."""
    enc = arr[_ENCAP]
    ok = (enc[:, 0] == 0) & (enc[:, 1] == 1)
    for leaf, count in zip(plan.dynamic, key, strict=True):
        ok &= arr[f"{leaf.path}#n"] == count
    return ok


def _check_terminators(plan: _Plan, arr: np.ndarray, key: tuple[int, ...], idx: np.ndarray) -> None:
    for leaf, count in zip(plan.dynamic, key, strict=True):
        if leaf.kind == "string" and count > 0:
            bad = np.flatnonzero(arr[f"{leaf.path}#nul"] != 0)
            if bad.size:
                raise CdrError(
                    f"{plan.spec.name}: payload {int(idx[bad[0]])}: string field "
                    f"{leaf.path!r} is not NUL-terminated"
                )


def _decode_strings(plan: _Plan, leaf: _Leaf, raw: np.ndarray, idx: np.ndarray) -> np.ndarray:
    try:
        return raw.astype(f"U{max(raw.dtype.itemsize, 1)}")
    except UnicodeDecodeError:
        pass
    out = []
    for j, b in enumerate(raw.tolist()):
        try:
            out.append(b.decode("utf-8"))
        except UnicodeDecodeError as exc:
            raise CdrError(
                f"{plan.spec.name}: payload {int(idx[j])}: string field {leaf.path!r} is not "
                f"valid UTF-8"
            ) from exc
    return np.array(out, dtype=str)


def decode_batch(
    type_name: str | MessageSpec,
    payloads: Sequence[bytes],
    *,
    schema_text: str | None = None,
) -> dict[str, np.ndarray]:
    """Decode many CDR payloads of one type into columns keyed by dotted field path.

    Payloads sharing a shape (found from their length prefixes; a topic's messages nearly
    always share one) are viewed together through one structured dtype. Columns keep the input
    order: numbers in their native dtypes (bool as bool), strings as a numpy ``str`` array,
    fixed arrays ``(n, N)``, sequences ``(n, len)`` when every message has the same length and
    otherwise an object array of 1-D arrays. A sequence of messages becomes an object array
    holding, per message, a dict of columns of its elements.

    ``type_name`` names a toolkit type, or pass a :class:`MessageSpec`, or pass the log's own
    ``schema_text`` to decode by the definition the log carries. Truncated or inconsistent
    payloads raise :class:`CdrError` naming the payload and field.
    """
    plan = _resolve(type_name, schema_text)
    if plan.complex:
        return _decode_slow(plan, payloads, schema_text)
    n = len(payloads)
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=n)
    groups: list[tuple[np.ndarray, np.ndarray, tuple[int, ...]]] = []
    remaining = np.arange(n)
    # Guess and check: take the first unread payload's shape, view every unread payload of the
    # same length through it, keep those whose prefixes agree. A few rounds cover the usual
    # handful of shapes; whatever is left after that is read one payload at a time.
    for _ in range(_GUESS_ROUNDS):
        if not remaining.size:
            break
        first = int(remaining[0])
        key, end = plan.walk(payloads[first], first)
        cand = remaining[lengths[remaining] == lengths[first]]
        arr = _view(plan, payloads, cand, key, int(lengths[first]), end)
        ok = _check_group(plan, arr, key)
        groups.append((cand[ok], arr[ok], key))
        unread = np.zeros(n, dtype=bool)
        unread[remaining] = True
        unread[cand[ok]] = False
        remaining = np.flatnonzero(unread)
    by_shape: dict[tuple[tuple[int, ...], int], tuple[list[int], int]] = {}
    for i in remaining.tolist():
        k, end = plan.walk(payloads[i], i)
        by_shape.setdefault((k, int(lengths[i])), ([], end))[0].append(i)
    for (k, size), (members, end) in by_shape.items():
        idx = np.asarray(members, dtype=np.int64)
        arr = _view(plan, payloads, idx, k, size, end)
        if not _check_group(plan, arr, k).all():  # cannot happen: walk() read these prefixes
            raise CdrError(f"{plan.spec.name}: inconsistent length prefixes")
        groups.append((idx, arr, k))
    for idx, arr, k in groups:
        _check_terminators(plan, arr, k, idx)
    return _assemble(plan, groups, n)


def _view(
    plan: _Plan,
    payloads: Sequence[bytes],
    idx: np.ndarray,
    key: tuple[int, ...],
    size: int,
    end: int,
) -> np.ndarray:
    """The payloads ``idx`` (all ``size`` bytes long) as one structured array of shape ``key``."""
    if size - end > _MAX_TRAILING:
        raise CdrError(
            f"{plan.spec.name}: payload {int(idx[0])} has {size - end} unexpected bytes after "
            f"its last field {plan.leaves[-1].path!r} (wrong message type?)"
        )
    dt = plan.layout(key, size)
    buf = b"".join([payloads[i] for i in idx.tolist()])
    return np.frombuffer(buf, dtype=dt)


def _assemble(
    plan: _Plan, groups: list[tuple[np.ndarray, np.ndarray, tuple[int, ...]]], n: int
) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    in_order = len(groups) == 1 and len(groups[0][0]) == n
    lengths_of = {leaf.path: i for i, leaf in enumerate(plan.dynamic)}
    for leaf in plan.leaves:
        if leaf.kind == "empty":
            continue
        path = leaf.path
        if leaf.kind in ("scalar", "fixed"):
            native = _native(leaf)
            shape: tuple[int, ...] = (n,) if leaf.kind == "scalar" else (n, leaf.count)
            if in_order:
                out[path] = groups[0][1][path].astype(native)
                continue
            col = np.empty(shape, dtype=native)
            for idx, arr, _ in groups:
                col[idx] = arr[path]
            out[path] = col
        elif leaf.kind == "string":
            parts = []
            for idx, arr, k in groups:
                nbytes = k[lengths_of[path]]
                if nbytes > 1:
                    parts.append((idx, _decode_strings(plan, leaf, arr[path], idx)))
                else:
                    parts.append((idx, np.full(len(idx), "", dtype="U1")))
            if in_order:
                out[path] = parts[0][1]
                continue
            width = max((p.dtype.itemsize // 4 for _, p in parts), default=1)
            scol = np.empty(n, dtype=f"U{max(width, 1)}")
            for idx, p in parts:
                scol[idx] = p
            out[path] = scol
        else:  # primitive sequence
            native = _native(leaf)
            counts = {k[lengths_of[path]] for _, _, k in groups}
            if len(counts) <= 1:
                count = counts.pop() if counts else 0
                if in_order:
                    out[path] = (
                        groups[0][1][path].astype(native)
                        if count
                        else np.zeros((n, 0), dtype=native)
                    )
                    continue
                col = np.zeros((n, count), dtype=native)
                if count:
                    for idx, arr, _ in groups:
                        col[idx] = arr[path]
                out[path] = col
            else:
                ocol = np.empty(n, dtype=object)
                for idx, arr, k in groups:
                    count = k[lengths_of[path]]
                    block = (
                        arr[path].astype(native) if count else np.zeros((len(idx), 0), dtype=native)
                    )
                    for j, i in enumerate(idx.tolist()):
                        ocol[i] = block[j]
                out[path] = ocol
    return out


__all__ = [
    "CDR_LE_HEADER",
    "PRIMITIVE_DTYPES",
    "decode_batch",
    "encode_batch",
    "encode_message",
    "layout",
]

"""Decoding a batch of ROS 2 CDR payloads into numpy columns, a whole chunk at a time.

Ingest hands :func:`decode_batch` every payload of one topic in an MCAP chunk (thousands of
laser scans, IMU samples...) and gets back one numpy array per dotted field path. Decoding them
one by one in Python would take seconds per chunk; this takes milliseconds, because payloads
that share a *shape* (the lengths of their strings and sequences) share one fixed layout
(:mod:`toolkit.mcapio.cdr_layout`, where the CDR rules are written down):

1. Read the length prefixes of the first payload
   (:meth:`~toolkit.mcapio.cdr_layout.Plan.read_shape`) to learn its shape, and build the
   structured dtype of that shape.
2. Join every not-yet-decoded payload of the same byte length and view them all through that
   dtype at once; keep those whose header and length prefixes agree with the shape.
3. Repeat a few times for the other shapes; read what is left one payload at a time.
4. Check the string terminators, decode the strings as UTF-8, and assemble each column in the
   input order.

Types without a fixed layout (arrays of nested messages or of strings: ``tf2_msgs/TFMessage``,
``terrain_msgs/RoughFeatureArray``) are decoded one message at a time by ``mcap_ros2``'s public
decoder (:class:`mcap_ros2.decoder.DecoderFactory`), then turned into the same kind of columns.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap_ros2.decoder import DecoderFactory
from numpy.typing import NDArray

from toolkit.errors import CdrError, SchemaError
from toolkit.mcapio.cdr_layout import (
    ENCAP,
    Leaf,
    Plan,
    check_header,
    length_name,
    nul_name,
    plan_for,
    plan_for_spec,
)
from toolkit.mcapio.msgdefs import MessageSpec, full_type_name, load_msgdef

#: Most trailing bytes tolerated after the last field (some DDS layers pad to a multiple of 4).
MAX_TRAILING = 7
#: Shapes guessed and checked in bulk by decode_batch before it reads payloads one by one.
GUESS_ROUNDS = 4

#: Decoded columns keyed by dotted field path (see :func:`decode_batch`).
Columns = dict[str, NDArray[Any]]

#: One group of same-shaped payloads: their indices in the batch ``(m,)``, the structured
#: array viewing them ``(m,)``, and their shape key.
_Group = tuple[NDArray[np.intp], NDArray[np.void], tuple[int, ...]]


def decode_batch(
    type_name: str | MessageSpec,
    payloads: Sequence[bytes],
    *,
    schema_text: str | None = None,
) -> Columns:
    """Decode many CDR payloads of one type into columns keyed by dotted field path.

    Payloads sharing a shape (found from their length prefixes; a topic's messages nearly
    always share one) are viewed together through one structured dtype. For ``n`` payloads,
    columns keep the input order: numbers ``(n,)`` in their native dtypes (bool as bool),
    strings as a numpy ``str`` array ``(n,)``, fixed arrays ``(n, N)``, sequences ``(n, len)``
    when every message has the same length and otherwise an object array ``(n,)`` of 1-D
    arrays. A sequence of messages becomes an object array ``(n,)`` holding, per message, a
    dict of columns of its elements.

    ``type_name`` names a toolkit type, or pass a :class:`MessageSpec`, or pass the log's own
    ``schema_text`` to decode by the definition the log carries (with a spec parsed from it,
    pass the text too: a type without a fixed layout is decoded message by message from the
    text, and a spec alone is refused as :class:`SchemaError` rather than decoded by the
    toolkit's own text). Truncated or inconsistent payloads raise :class:`CdrError` naming the
    payload and field.
    """
    plan = plan_for(type_name, schema_text)
    if not plan.has_fixed_layout:
        if isinstance(type_name, MessageSpec) and schema_text is None:
            raise SchemaError(f"{plan.name}: decoding a parsed definition needs its schema text")
        return _decode_per_message(plan, payloads, schema_text)
    n = len(payloads)
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=n)
    groups: list[_Group] = []
    remaining = np.arange(n)
    # Guess and check: take the first unread payload's shape, view every unread payload of the
    # same length through it, keep those whose prefixes agree. A few rounds cover the usual
    # handful of shapes; whatever is left after that is read one payload at a time.
    for _ in range(GUESS_ROUNDS):
        if not remaining.size:
            break
        first = int(remaining[0])
        key, end = plan.read_shape(payloads[first], first)
        cand = remaining[lengths[remaining] == lengths[first]]
        arr = _view(plan, payloads, cand, key, int(lengths[first]), end)
        ok = _matches_shape(plan, arr, key)
        groups.append((cand[ok], arr[ok], key))
        unread = np.zeros(n, dtype=bool)
        unread[remaining] = True
        unread[cand[ok]] = False
        remaining = np.flatnonzero(unread)
    by_shape: dict[tuple[tuple[int, ...], int], tuple[list[int], int]] = {}
    for i in remaining.tolist():
        k, end = plan.read_shape(payloads[i], i)
        by_shape.setdefault((k, int(lengths[i])), ([], end))[0].append(i)
    for (k, size), (members, end) in by_shape.items():
        idx = np.asarray(members, dtype=np.intp)
        arr = _view(plan, payloads, idx, k, size, end)
        if not _matches_shape(plan, arr, k).all():  # cannot happen: read_shape read these
            raise CdrError(f"{plan.name}: inconsistent length prefixes")
        groups.append((idx, arr, k))
    for idx, arr, k in groups:
        _check_terminators(plan, arr, k, idx)
    return _assemble(plan, groups, n)


# --------------------------------------------------------------------------------------------
# The vectorised path
# --------------------------------------------------------------------------------------------


def _view(
    plan: Plan,
    payloads: Sequence[bytes],
    idx: NDArray[np.intp],
    key: tuple[int, ...],
    size: int,
    end: int,
) -> NDArray[np.void]:
    """The payloads ``idx`` (all ``size`` bytes long) as one structured array ``(len(idx),)``
    of shape ``key``; ``end`` is where the last field ends (trailing padding is tolerated)."""
    if size - end > MAX_TRAILING:
        raise CdrError(
            f"{plan.name}: payload {int(idx[0])} has {size - end} unexpected bytes after "
            f"its last field {plan.leaves[-1].path!r} (wrong message type?)"
        )
    dt = plan.layout(key, size)
    buf = b"".join([payloads[i] for i in idx.tolist()])
    return np.frombuffer(buf, dtype=dt)


def _matches_shape(plan: Plan, arr: NDArray[np.void], key: tuple[int, ...]) -> NDArray[np.bool_]:
    """Rows ``(m,)`` of a candidate group whose header and length prefixes match ``key``."""
    enc = arr[ENCAP]
    ok: NDArray[np.bool_] = (enc[:, 0] == 0) & (enc[:, 1] == 1)
    for leaf, count in zip(plan.dynamic, key, strict=True):
        ok &= arr[length_name(leaf.path)] == count
    return ok


def _check_terminators(
    plan: Plan, arr: NDArray[np.void], key: tuple[int, ...], idx: NDArray[np.intp]
) -> None:
    """Refuse the group if any of its strings does not end in a NUL byte."""
    for leaf, count in zip(plan.dynamic, key, strict=True):
        if leaf.kind == "string" and count > 0:
            bad = np.flatnonzero(arr[nul_name(leaf.path)] != 0)
            if bad.size:
                raise CdrError(
                    f"{plan.name}: payload {int(idx[bad[0]])}: string field "
                    f"{leaf.path!r} is not NUL-terminated"
                )


def _decode_strings(
    plan: Plan, leaf: Leaf, raw: NDArray[np.bytes_], idx: NDArray[np.intp]
) -> NDArray[np.str_]:
    """UTF-8 bytes ``(m,)`` -> str ``(m,)``; the fast ASCII cast first, then one by one."""
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
                f"{plan.name}: payload {int(idx[j])}: string field {leaf.path!r} is not valid UTF-8"
            ) from exc
    return np.array(out, dtype=str)


def _native_dtype(leaf: Leaf) -> np.dtype[Any]:
    """The dtype a decoded column of ``leaf`` has: the wire dtype in native byte order, bool
    for bool fields."""
    if leaf.is_bool:
        return np.dtype(bool)
    if leaf.dtype is None:
        raise CdrError(f"field {leaf.path!r} ({leaf.type_name}) is not a primitive field")
    return leaf.dtype.newbyteorder("=")


def _assemble(plan: Plan, groups: list[_Group], n: int) -> Columns:
    """Gather every group's fields into columns of ``n`` rows in the input order."""
    out: Columns = {}
    in_order = len(groups) == 1 and len(groups[0][0]) == n
    lengths_of = {leaf.path: i for i, leaf in enumerate(plan.dynamic)}
    for leaf in plan.leaves:
        if leaf.kind == "empty":
            continue
        path = leaf.path
        if leaf.kind in ("scalar", "fixed"):
            native = _native_dtype(leaf)
            shape: tuple[int, ...] = (n,) if leaf.kind == "scalar" else (n, leaf.count)
            if in_order:
                out[path] = groups[0][1][path].astype(native)
                continue
            col = np.empty(shape, dtype=native)
            for idx, arr, _ in groups:
                col[idx] = arr[path]
            out[path] = col
        elif leaf.kind == "string":
            out[path] = _assemble_strings(plan, leaf, groups, n, lengths_of[path], in_order)
        else:  # primitive sequence
            out[path] = _assemble_sequence(leaf, groups, n, lengths_of[path], in_order)
    return out


def _assemble_strings(
    plan: Plan, leaf: Leaf, groups: list[_Group], n: int, which: int, in_order: bool
) -> NDArray[np.str_]:
    """A string column ``(n,)``; ``which`` is the leaf's position in the shape key."""
    parts = []
    for idx, arr, k in groups:
        if k[which] > 1:
            parts.append((idx, _decode_strings(plan, leaf, arr[leaf.path], idx)))
        else:
            parts.append((idx, np.full(len(idx), "", dtype="U1")))
    if in_order:
        return parts[0][1]
    width = max((p.dtype.itemsize // 4 for _, p in parts), default=1)
    col = np.empty(n, dtype=f"U{max(width, 1)}")
    for idx, p in parts:
        col[idx] = p
    return col


def _assemble_sequence(
    leaf: Leaf, groups: list[_Group], n: int, which: int, in_order: bool
) -> NDArray[Any]:
    """A sequence column: ``(n, len)`` if every message has the same length, else an object
    array ``(n,)`` of 1-D arrays; ``which`` is the leaf's position in the shape key."""
    native = _native_dtype(leaf)
    counts = {k[which] for _, _, k in groups}
    if len(counts) <= 1:
        count = counts.pop() if counts else 0
        if in_order:
            if not count:
                return np.zeros((n, 0), dtype=native)
            return groups[0][1][leaf.path].astype(native)
        col = np.zeros((n, count), dtype=native)
        if count:
            for idx, arr, _ in groups:
                col[idx] = arr[leaf.path]
        return col
    ocol = np.empty(n, dtype=object)
    for idx, arr, k in groups:
        count = k[which]
        block = arr[leaf.path].astype(native) if count else np.zeros((len(idx), 0), dtype=native)
        for j, i in enumerate(idx.tolist()):
            ocol[i] = block[j]
    return ocol


# --------------------------------------------------------------------------------------------
# The per-message path, for types without a fixed layout
# --------------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _message_decoder(type_name: str, schema_text: str | None) -> Callable[[bytes], object]:
    """``mcap_ros2``'s decoder of one payload of ``type_name`` (cached per definition)."""
    name = full_type_name(type_name)
    text = load_msgdef(name) if schema_text is None else schema_text
    schema = Schema(id=1, name=name, encoding=SchemaEncoding.ROS2, data=text.encode())
    try:
        decoder = DecoderFactory().decoder_for(MessageEncoding.CDR, schema)
    except Exception as exc:  # the parser behind it raises assorted exception types
        raise SchemaError(f"cannot build a decoder for {name}: {exc}") from exc
    if decoder is None:
        raise SchemaError(f"cannot build a decoder for {name}")
    return decoder


def _decode_per_message(plan: Plan, payloads: Sequence[bytes], schema_text: str | None) -> Columns:
    decoder = _message_decoder(plan.name, schema_text)
    objs: list[object] = []
    for i, data in enumerate(payloads):
        check_header(plan.name, data, i)
        try:
            objs.append(decoder(data))
        except Exception as exc:  # struct.error, IndexError, UnicodeDecodeError...
            raise CdrError(f"{plan.name}: payload {i} cannot be decoded: {exc!r}") from exc
    return _objects_to_columns(plan, objs)


def _objects_to_columns(plan: Plan, objs: Sequence[object]) -> Columns:
    """Decoded message objects ``(n,)`` -> columns keyed by dotted path (nested arrays of
    messages become, per message, a dict of columns of their elements)."""
    out: Columns = {}
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
            out[leaf.path] = _complex_column(leaf, values)
        elif leaf.kind == "string":
            out[leaf.path] = np.array(values, dtype=str)
        elif leaf.kind == "scalar":
            out[leaf.path] = np.array(values, dtype=_native_dtype(leaf))
        else:
            rows = [
                np.frombuffer(v, np.uint8) if isinstance(v, bytes) else np.asarray(v)
                for v in values
            ]
            out[leaf.path] = _stack_rows(rows, _native_dtype(leaf))
    return out


def _complex_column(leaf: Leaf, values: Sequence[Any]) -> NDArray[np.object_]:
    """Per message, the columns of its array of messages, or its array of strings."""
    f = leaf.spec
    if f is None:
        raise CdrError(f"field {leaf.path!r} has no definition")
    col = np.empty(len(values), dtype=object)
    for i, v in enumerate(values):
        if f.nested is not None:
            col[i] = _objects_to_columns(plan_for_spec(f.nested), v)
        else:
            col[i] = np.array(list(v), dtype=str)
    return col


def _stack_rows(rows: Sequence[NDArray[Any]], dtype: np.dtype[Any]) -> NDArray[Any]:
    """Equal-length rows -> a 2-D array; otherwise an object array of 1-D arrays."""
    if len({len(r) for r in rows}) <= 1:
        if not rows:
            return np.zeros((0, 0), dtype=dtype)
        return np.stack([np.asarray(r, dtype=dtype) for r in rows])
    col = np.empty(len(rows), dtype=object)
    for i, r in enumerate(rows):
        col[i] = np.asarray(r, dtype=dtype)
    return col


__all__ = ["Columns", "decode_batch"]

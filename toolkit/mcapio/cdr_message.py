"""Encoding one ROS 2 message, given as a dict, into a CDR payload.

This is the simple, general encoder: it walks the message's fields in wire order and appends
each to a growing buffer, padding to the alignment the CDR rules ask for (they are listed in
:mod:`toolkit.mcapio.cdr_layout`). It handles every message type, including those without a
fixed layout (arrays of nested messages or of strings: ``tf2_msgs/TFMessage``,
``terrain_msgs/RoughFeatureArray``), for which :func:`~toolkit.mcapio.cdr_encode.encode_batch`
calls it once per message. For everything else the vectorised ``encode_batch`` is much faster
and writes the same bytes (the tests check that, and check both against ``mcap_ros2``'s writer).

A message is a mapping from field name to value, nested for nested messages
(``{"header": {"stamp": {"sec": 1}}}``), or keyed by dotted paths (``{"header.stamp.sec": 1}``),
or a mix of both. An array of messages is a list of such mappings. Values may be Python or
numpy numbers, numpy arrays, lists, ``str`` or ``bytes``, checked as
:mod:`toolkit.mcapio.cdr_values` describes. Fields left out (or given as None) take their
defaults; a key that names no field is an error.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.errors import CdrError
from toolkit.mcapio.cdr_layout import CDR_LE_HEADER, U32, Leaf, Plan, plan_for
from toolkit.mcapio.cdr_values import default_value, utf8, wire_array, wire_bytes_array
from toolkit.mcapio.msgdefs import MessageSpec

#: One message: field name (or dotted path) -> value; nested messages are mappings too.
Message = Mapping[str, object]


class _Buffer:
    """A CDR payload being written: the header, then fields appended with their alignment."""

    def __init__(self) -> None:
        self.data = bytearray(CDR_LE_HEADER)

    def pad_to(self, size: int) -> None:
        """Append zero bytes until the next field of alignment ``size`` may start."""
        if size > 1:
            self.data.extend(bytes(-(len(self.data) - len(CDR_LE_HEADER)) % size))

    def write_array(self, arr: NDArray[Any]) -> None:
        """Append the elements of a primitive array (or 0-d scalar), aligned to their size."""
        self.pad_to(arr.dtype.itemsize)
        self.data.extend(arr.tobytes())

    def write_length(self, length: int) -> None:
        """Append a uint32 length prefix (of a string or a sequence)."""
        if not 0 <= length <= 0xFFFFFFFF:
            raise CdrError(f"a string or sequence of {length} elements does not fit a uint32")
        self.pad_to(4)
        self.data.extend(U32.pack(length))

    def write_string(self, raw: bytes) -> None:
        """Append a string: its length including the NUL, its bytes, the NUL."""
        self.write_length(len(raw) + 1)
        self.data.extend(raw)
        self.data.append(0)


def encode_message(type_name: str | MessageSpec, msg: Message) -> bytes:
    """Encode one message of ``type_name`` (``pkg/msg/Type`` or a parsed spec) to CDR.

    ``msg`` is a nested dict (``{"header": {"stamp": {"sec": 1}}}``) or a dict of dotted paths;
    numpy arrays and scalars are accepted. Missing fields take their defaults. Returns the whole
    payload, CDR header included. Raises :class:`CdrError` for an unknown field or a value
    that does not fit its field.
    """
    plan = plan_for(type_name)
    out = _Buffer()
    _write_message(out, plan, msg, "")
    return bytes(out.data)


def _write_message(out: _Buffer, plan: Plan, msg: object, where: str) -> None:
    """Append the fields of one message (or nested message) ``msg``; ``where`` prefixes paths
    in error messages (``"transforms[2]."``)."""
    if not isinstance(msg, Mapping):
        raise CdrError(f"{plan.name}: {where or 'message'} must be a mapping of fields")
    values = _flat_values(msg)
    unknown = sorted(set(values) - plan.paths)
    if unknown:
        raise CdrError(f"{plan.name} has no field {', '.join(repr(where + k) for k in unknown)}")
    for leaf in plan.leaves:
        value = values[leaf.path] if leaf.path in values else default_value(leaf)
        _write_leaf(out, leaf, value, f"{where}{leaf.path}")


def _flat_values(msg: Mapping[str, object], prefix: str = "") -> dict[str, object]:
    """``{"a": {"b": 1}, "c.d": 2}`` -> ``{"a.b": 1, "c.d": 2}``: every value by dotted path.

    Recursion stops at anything that is not a mapping, so a list of messages stays one value.
    None values are left out, so that those fields take their defaults.
    """
    out: dict[str, object] = {}
    for key, value in msg.items():
        path = f"{prefix}{key}"
        if value is None:  # not given: the field keeps its default
            continue
        if isinstance(value, Mapping):
            out.update(_flat_values(value, f"{path}."))
        else:
            out[path] = value
    return out


def _write_leaf(out: _Buffer, leaf: Leaf, value: object, path: str) -> None:
    if leaf.kind in ("scalar", "empty"):
        arr = wire_array(path, leaf, value)
        if arr.ndim != 0:
            raise CdrError(f"field {path!r} is a scalar field, got shape {arr.shape}")
        out.write_array(arr)
    elif leaf.kind == "fixed":
        arr = _array_value(path, leaf, value)
        if arr.shape != (leaf.count,):
            raise CdrError(
                f"field {path!r} is {leaf.type_name}[{leaf.count}], got shape {arr.shape}"
            )
        out.write_array(arr)
    elif leaf.kind == "sequence":
        arr = _array_value(path, leaf, value)
        if arr.ndim != 1:
            raise CdrError(f"field {path!r} is {leaf.type_name}[], got shape {arr.shape}")
        out.write_length(len(arr))
        if len(arr):
            out.write_array(arr)
    elif leaf.kind == "string":
        out.write_string(utf8(path, value))
    else:
        _write_complex(out, leaf, value, path)


def _array_value(path: str, leaf: Leaf, value: object) -> NDArray[Any]:
    if isinstance(value, bytes | bytearray):
        return wire_bytes_array(path, leaf, value)
    return wire_array(path, leaf, value)


def _write_complex(out: _Buffer, leaf: Leaf, value: object, path: str) -> None:
    """An array of messages or of strings: its count (unless fixed-size), then each element."""
    f = leaf.spec
    if f is None:
        raise CdrError(f"field {path!r} has no definition")
    items = _items(path, value)
    if f.array_length is not None:
        if len(items) != f.array_length:
            raise CdrError(f"field {path!r} holds {f.array_length} elements, got {len(items)}")
    else:
        out.write_length(len(items))
    if f.nested is None:  # array of strings
        for j, item in enumerate(items):
            out.write_string(utf8(f"{path}[{j}]", item))
        return
    element = plan_for(f.nested)
    for j, item in enumerate(items):
        _write_message(out, element, {} if item is None else item, f"{path}[{j}].")


def _items(path: str, value: object) -> Sequence[object]:
    """The elements of an array-of-messages or array-of-strings value (None: no elements)."""
    if value is None:
        return []
    if isinstance(value, np.ndarray) and value.ndim == 1:
        return list(value)
    if isinstance(value, list | tuple):
        return value
    raise CdrError(f"field {path!r} is an array, got {type(value).__name__}")


__all__ = ["Message", "encode_message"]

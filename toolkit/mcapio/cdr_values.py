"""Caller values made ready for the wire: checked numpy arrays, UTF-8 bytes, field defaults.

Both encoders (:mod:`toolkit.mcapio.cdr_encode` for batches, :mod:`toolkit.mcapio.cdr_message`
for single messages) take what the caller gives for a field (a Python number, a numpy scalar or
array, a list, a string) and turn it into exactly the bytes the wire holds. They share these
rules so that a value is accepted, or refused, the same way by both:

- a number goes to its field's wire dtype only if nothing is lost: floating-point values are
  refused for integer and bool fields, integers outside the field's range are refused;
- a bool field stores ``value != 0``;
- strings are UTF-8 (``bytes`` are taken as already encoded);
- a field left out takes the default its ``.msg`` declares, else zero, ``""`` or empty.

Every refusal is a :class:`~toolkit.errors.CdrError` naming the field's dotted path.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.errors import CdrError
from toolkit.mcapio.cdr_layout import Leaf

#: What a field left out is encoded as: see :func:`default_value`.
DefaultColumn = int | float | bool | str | NDArray[np.generic] | tuple[object, ...] | None


def wire_array(path: str, leaf: Leaf, value: object) -> NDArray[Any]:
    """``value`` as an array of ``leaf``'s wire dtype, refusing lossy or out-of-range input.

    The array keeps the shape of ``value`` (0-d for a scalar, ``(n,)`` or ``(n, count)`` for a
    column); an empty input of any numeric dtype gives an empty array of the wire dtype.
    """
    if leaf.dtype is None:
        raise CdrError(f"field {path!r} ({leaf.type_name}) is not a primitive field")
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


def wire_bytes_array(path: str, leaf: Leaf, value: bytes | bytearray) -> NDArray[Any]:
    """A ``bytes`` value of a ``uint8``/``byte`` array field as a 1-D array of its wire dtype."""
    return wire_array(path, leaf, np.frombuffer(value, dtype=np.uint8))


def utf8_array(path: str, value: object) -> NDArray[np.bytes_]:
    """A 1-D array of str (or of bytes, taken as encoded) -> a bytes (``S``) array of UTF-8."""
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


def utf8(path: str, value: object) -> bytes:
    """One string value as its UTF-8 bytes (``bytes`` are taken as already encoded)."""
    if isinstance(value, bytes):
        return value
    if isinstance(value, str):
        try:
            return value.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise CdrError(f"field {path!r} (string): {exc}") from exc
    raise CdrError(f"field {path!r} (string) got {type(value).__name__}, expected str")


def default_value(leaf: Leaf) -> DefaultColumn:
    """The value of a field the caller leaves out: its declared default, else zero or empty.

    None for a field that is an array of messages or strings with no declared default.
    """
    f = leaf.spec
    default = f.default if f is not None else None
    if leaf.kind in ("scalar", "empty"):
        return 0 if default is None else default
    if leaf.kind == "fixed":
        return np.zeros(leaf.count) if default is None else np.asarray(default)
    if leaf.kind == "string":
        return "" if default is None else str(default)
    if leaf.kind == "sequence":
        return np.zeros(0) if default is None else np.asarray(default)
    return default if isinstance(default, tuple) else None


__all__ = ["DefaultColumn", "default_value", "utf8", "utf8_array", "wire_array", "wire_bytes_array"]

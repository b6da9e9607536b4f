"""Fixed-point storage of float columns: metres kept to the millimetre in 32 bits.

A column whose schema gives ``decimal_places: k`` holds float64 values in memory and is
stored as the whole number ``n = rint(v * 10**k)`` in a Parquet ``DECIMAL(9, k)`` column of
physical type INT32 (``store_decimal_as_integer``): the value is exact to half a step
(0.5 mm at k = 3), and every Parquet reader shows it in the column's own unit (pyarrow and
polars as a decimal, ``1.234``). Read back through :mod:`toolkit.tableio` it is float64
again, ``n / 10**k``: the float nearest the stored decimal, the same bits on every machine.

Why: the point cloud is most of a workspace. Its coordinates as float64 cost ~6 bytes a
point each after zstd (their low bits are noise), as whole millimetres, delta-encoded
(neighbouring beams of a scan land centimetres apart), ~1.4 (measured on 7.1 M points of a
20-mile race; ``benchmarks/README.md``). float32 would keep millimetres only within 16 km of
the origin and compress worse (3.3 bytes a coordinate, the same measurement).

A decimal of precision 9 holds ``|v| < 10**(9 - k)``: a million metres at k = 3, a
thousand rad/s at k = 6. A value outside, or not finite, cannot be stored and is an error
naming the column (:class:`~toolkit.errors.SchemaError`, raised by the caller).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

#: Digits of a DECIMAL stored as INT32 (Parquet allows 1-9).
PRECISION = 9


class FixedPointRangeError(ValueError):
    """A value that the column's fixed point cannot hold; ``value`` is the first such."""

    def __init__(self, value: float, places: int) -> None:
        limit = 10.0 ** (PRECISION - places)
        super().__init__(
            f"value {value!r} cannot be stored to {places} decimal places (|v| < {limit:g})"
        )
        self.value = value


def storage_type(places: int) -> pa.DataType:
    """The Arrow type a column of ``places`` decimal places is stored as."""
    return pa.decimal32(PRECISION, places)


def encode(values: pa.Array | pa.ChunkedArray, places: int) -> pa.Array:
    """float64 values (N,) -> the decimal32 array (N,) of ``rint(v * 10**places)``.

    Rounds half to even (numpy's ``rint``); raises :class:`FixedPointRangeError` on a value
    that is not finite or too large for :data:`PRECISION` digits."""
    v = np.asarray(values.to_numpy(zero_copy_only=False), dtype=np.float64)
    scaled = np.rint(v * 10.0**places)
    limit = 10.0**PRECISION
    bad = ~(np.abs(scaled) < limit)  # NaN compares False: caught here too
    if bad.any():
        raise FixedPointRangeError(float(v[np.flatnonzero(bad)[0]]), places)
    whole = scaled.astype(np.int32)
    return pa.Array.from_buffers(storage_type(places), len(whole), [None, pa.py_buffer(whole)])


def decode(values: pa.Array | pa.ChunkedArray) -> pa.Array:
    """A decimal32 array (N,) -> float64 (N,): each stored whole number over 10**scale,
    correctly rounded (one IEEE division)."""
    chunks = values.chunks if isinstance(values, pa.ChunkedArray) else [values]
    parts: list[NDArray[np.float64]] = []
    for chunk in chunks:
        if chunk.null_count:
            raise ValueError("a fixed-point column holds nulls")
        whole = np.frombuffer(chunk.buffers()[1], dtype=np.int32)
        whole = whole[chunk.offset : chunk.offset + len(chunk)]
        parts.append(whole / 10.0**chunk.type.scale)
    out = np.concatenate(parts) if parts else np.empty(0, dtype=np.float64)
    return pa.array(out, type=pa.float64())


def is_stored(tp: pa.DataType) -> bool:
    """True for the type :func:`storage_type` makes (a decimal32)."""
    return isinstance(tp, pa.Decimal32Type)

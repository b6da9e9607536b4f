"""Shared helpers for the mcapio tests: random message columns and reference comparisons.

Columns are generated generically from the parsed message definitions, so every message type
the toolkit ships is exercised the same way. Comparisons go through ``mcap_ros2``'s reference
decoder, never through the code under test.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from toolkit.mcapio.msgdefs import FieldSpec, MessageSpec, load_msgdef, parse_msgdef

NUMPY_TYPES = {
    "bool": np.bool_,
    "byte": np.uint8,
    "char": np.uint8,
    "uint8": np.uint8,
    "int8": np.int8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}

WORDS = ["base_link", "laser_front_left", "", "imu", "gps_antenna_é", "map", "x"]


@dataclass(frozen=True)
class Leaf:
    path: str
    field: FieldSpec


def leaves(spec: MessageSpec, prefix: str = "") -> Iterator[Leaf]:
    """The dotted-path leaves of a spec (nested non-array messages are flattened)."""
    for f in spec.fields:
        if f.nested is not None and not f.is_array:
            yield from leaves(f.nested, f"{prefix}{f.name}.")
        else:
            yield Leaf(f"{prefix}{f.name}", f)


def _values(rng: np.random.Generator, type_name: str, shape: tuple[int, ...]) -> np.ndarray:
    dtype = NUMPY_TYPES[type_name]
    if type_name == "bool":
        return rng.random(shape) < 0.5
    if np.issubdtype(dtype, np.floating):
        return rng.normal(0.0, 100.0, shape).astype(dtype)
    info = np.iinfo(dtype)
    lo, hi = max(int(info.min), -(2**40)), min(int(info.max), 2**40)
    return rng.integers(lo, hi, shape, endpoint=True).astype(dtype)


def random_columns(
    spec: MessageSpec | str, n: int, rng: np.random.Generator, *, vary: bool
) -> dict[str, Any]:
    """Random columns for ``n`` messages; ``vary`` makes string and sequence lengths differ."""
    if isinstance(spec, str):
        spec = parse_msgdef(spec)
    cols: dict[str, Any] = {}
    for leaf in leaves(spec):
        f = leaf.field
        if f.nested is not None:  # array of messages: per row, a mapping of element columns
            counts = rng.integers(0, 4, n) if vary else np.full(n, 2)
            cols[leaf.path] = [
                random_columns(f.nested, int(k), rng, vary=vary) for k in counts.tolist()
            ]
        elif f.is_string:
            if vary:
                cols[leaf.path] = np.array([WORDS[i] for i in rng.integers(0, len(WORDS), n)])
            else:
                cols[leaf.path] = "base_link"
        elif not f.is_array:
            cols[leaf.path] = _values(rng, f.type_name, (n,))
        elif f.array_length is not None:
            cols[leaf.path] = _values(rng, f.type_name, (n, f.array_length))
        elif vary:
            cols[leaf.path] = [
                _values(rng, f.type_name, (int(k),)) for k in rng.integers(0, 6, n).tolist()
            ]
        else:
            cols[leaf.path] = _values(rng, f.type_name, (n, 5))
    return cols


def row(spec: MessageSpec, cols: Mapping[str, Any], i: int) -> dict[str, Any]:
    """Row ``i`` of a columns mapping as a flat dict (dotted keys) for encode_message."""
    out: dict[str, Any] = {}
    for leaf in leaves(spec):
        value = cols[leaf.path]
        if isinstance(value, str):
            out[leaf.path] = value
            continue
        v = value[i]
        if leaf.field.nested is not None:
            k = _rows(v)
            out[leaf.path] = [row(leaf.field.nested, v, j) for j in range(k)]
        else:
            out[leaf.path] = v
    return out


def _rows(cols: Mapping[str, Any]) -> int:
    for v in cols.values():
        if not isinstance(v, str):
            return len(v)
    return 0


def expected(cols: Mapping[str, Any], path: str, i: int) -> Any:
    value = cols[path]
    return value if isinstance(value, str) else value[i]


def reference_decoder(type_name: str) -> Callable[[bytes], Any]:
    schema = Schema(id=1, name=type_name, encoding="ros2msg", data=load_msgdef(type_name).encode())
    decoder = DecoderFactory().decoder_for("cdr", schema)
    assert decoder is not None
    return decoder


def _get(obj: Any, path: str) -> Any:
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def assert_object_matches(spec: MessageSpec, obj: Any, cols: Mapping[str, Any], i: int) -> None:
    """A reference-decoded message equals row ``i`` of the columns it was encoded from."""
    for leaf in leaves(spec):
        f = leaf.field
        got = _get(obj, leaf.path)
        want = expected(cols, leaf.path, i)
        if f.nested is not None:
            assert len(got) == _rows(want), leaf.path
            for j, element in enumerate(got):
                assert_object_matches(f.nested, element, want, j)
        elif f.is_string:
            assert got == want, leaf.path
        else:
            dtype = NUMPY_TYPES[f.type_name]
            if isinstance(got, bytes):
                got = np.frombuffer(got, dtype=np.uint8)
            np.testing.assert_array_equal(np.asarray(got, dtype=dtype), want, err_msg=leaf.path)


def assert_columns_match(
    spec: MessageSpec, got: Mapping[str, Any], cols: Mapping[str, Any], n: int
) -> None:
    """decode_batch output equals the columns the messages were made from (row by row)."""
    assert set(got) == {leaf.path for leaf in leaves(spec)}
    for leaf in leaves(spec):
        f = leaf.field
        column = got[leaf.path]
        assert len(column) == n, leaf.path
        for i in range(n):
            want = expected(cols, leaf.path, i)
            if f.nested is not None:
                assert_columns_match(f.nested, column[i], want, _rows(want))
            elif f.is_string:
                assert column[i] == want, leaf.path
            else:
                dtype = NUMPY_TYPES[f.type_name]
                assert np.asarray(column[i]).dtype == dtype, leaf.path
                np.testing.assert_array_equal(column[i], want, err_msg=leaf.path)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240601)

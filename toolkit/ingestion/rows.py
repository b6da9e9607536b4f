"""A decoded batch as table rows: what every converter is handed and gives back.

:func:`~toolkit.mcapio.cdr.decode_batch` gives one numpy array per dotted field path, a whole
chunk of one topic at once; a converter (:mod:`toolkit.ingestion.converters`) turns them into
a :class:`RoleRows`, vectorised, with the column helpers here.

Time: ``t_ns`` is the header stamp (``sec * 1e9 + nanosec``, int64) corrected by the role's
declared clock offset and latency, ``stamp + clock_offset_ns - latency_ns``
(:meth:`~toolkit.config.TimeConfig.correction_ns`). A message whose stamp is zero carries no
stamp; it takes its log time instead, uncorrected, and is counted (``stamp_missing``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.config import LidarConfig, TimeConfig
from toolkit.mcapio.msgdefs import full_type_name

Columns = Mapping[str, Any]

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class ConvertContext:
    """What a converter needs besides the columns: who the topic is and the declared timing."""

    topic: str
    role: str
    type_name: str
    correction_ns: int
    #: How far a header stamp may be from its log time (``[time] max_header_skew_ns``).
    max_header_skew_ns: int = 0
    #: How a 3-D lidar's clouds are read (``[lidar]``); None for the other roles.
    lidar: LidarConfig | None = None

    @classmethod
    def for_topic(
        cls,
        topic: str,
        role: str,
        type_name: str,
        time: TimeConfig,
        lidar: LidarConfig | None = None,
    ) -> ConvertContext:
        """The context of one topic under the configuration's clocks (``[time]``)."""
        return cls(
            topic=topic,
            role=role,
            type_name=full_type_name(type_name),
            correction_ns=time.correction_ns(role),
            max_header_skew_ns=time.max_header_skew_ns,
            lidar=lidar,
        )


@dataclass
class RoleRows:
    """One decoded batch as table rows (one row per message, in message order).

    ``table`` holds ``t_ns`` and the table's columns. ``finite`` marks messages whose
    must-be-finite fields are finite; ``stamp_missing`` messages took their log time;
    ``counts`` are per-message counts of notable values (e.g. ``laser_no_return``), summed
    over the messages kept; ``metadata`` goes to the table's key-value metadata.

    Most roles give one row per message. A role whose message holds a list (tf_static,
    truth_features, a lidar's cloud) gives one row per element; ``message_of_row`` then says
    which message each row came from, and the header-skew check applies to the messages'
    ``message_t_ns`` when given (a cloud's stamp), not at all without (static data).
    ``span_ns`` is, for a message whose rows each have their own time (a lidar's sweep), the
    span of those times (-1 when unknown): ingest checks it against the topic's period.
    """

    table: pa.Table
    finite: BoolArray
    stamp_missing: BoolArray
    counts: dict[str, IntArray] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    message_of_row: IntArray | None = None
    message_t_ns: IntArray | None = None
    span_ns: IntArray | None = None

    @property
    def t_ns(self) -> IntArray:
        """The rows' corrected times as int64 nanoseconds."""
        return np.asarray(self.table.column("t_ns").to_numpy(), dtype=np.int64)

    @property
    def message_count(self) -> int:
        """How many messages the rows came from."""
        return len(self.finite)


Converter = Callable[[Columns, IntArray, ConvertContext], RoleRows]


def f64(cols: Columns, path: str) -> FloatArray:
    return np.asarray(cols[path], dtype=np.float64)


def stamp_times(
    cols: Columns, log_time_ns: IntArray, ctx: ConvertContext
) -> tuple[IntArray, BoolArray]:
    """Corrected ``t_ns`` from ``header.stamp`` and the mask of messages without a stamp.

    A zero stamp means none was set: such a message takes its log time, uncorrected.
    """
    sec = np.asarray(cols["header.stamp.sec"], dtype=np.int64)
    nsec = np.asarray(cols["header.stamp.nanosec"], dtype=np.int64)
    stamp = sec * NS_PER_S + nsec
    missing = (sec == 0) & (nsec == 0)
    t_ns = np.where(missing, np.asarray(log_time_ns, dtype=np.int64), stamp + ctx.correction_ns)
    return t_ns.astype(np.int64, copy=False), missing


def all_finite(*arrays: np.ndarray) -> BoolArray:
    ok = np.ones(len(arrays[0]), dtype=bool)
    for a in arrays:
        ok &= np.isfinite(a)
    return ok


def nullable(values: FloatArray, null: BoolArray) -> pa.Array:
    return pa.array(values, type=pa.float64(), mask=null)


def list_array(
    values_2d: np.ndarray, value_type: pa.DataType, null: BoolArray | None = None
) -> pa.Array:
    """An (n, k) array as a list array of n lists of k values (null rows where ``null``)."""
    n, k = values_2d.shape
    offsets = pa.array(np.arange(n + 1, dtype=np.int32) * np.int32(k), type=pa.int32())
    flat = pa.array(np.ascontiguousarray(values_2d).reshape(-1), type=value_type)
    mask = None if null is None else pa.array(null, type=pa.bool_())
    return pa.ListArray.from_arrays(offsets, flat, mask=mask)


def ragged_list_array(rows: np.ndarray, value_type: pa.DataType, dtype: Any) -> pa.Array:
    """An object array of 1-D arrays (lengths differ) as a list array."""
    lengths = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    offsets = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    flat = (
        np.concatenate([np.asarray(r, dtype=dtype) for r in rows])
        if len(rows)
        else np.zeros(0, dtype=dtype)
    )
    return pa.ListArray.from_arrays(
        pa.array(offsets.astype(np.int32), type=pa.int32()), pa.array(flat, type=value_type)
    )


def explode(
    per_msg: Any, fields: Mapping[str, str], dtypes: Mapping[str, Any]
) -> tuple[dict[str, np.ndarray], IntArray]:
    """Element columns of a sequence-of-messages field, concatenated over the messages.

    ``per_msg`` holds, per message, a dict of the elements' columns (as decode_batch gives a
    sequence of nested messages); ``fields`` maps output name -> element path. Returns the
    columns and the number of elements per message. Such messages (tf_static, truth features)
    come once per log, so the loop over messages costs nothing.
    """
    msgs = list(per_msg)
    first = next(iter(fields.values()))
    counts = np.array([len(np.asarray(m.get(first, []))) for m in msgs], dtype=np.int64)
    out: dict[str, np.ndarray] = {}
    for name, path in fields.items():
        dtype = dtypes.get(name, np.float64)
        parts = [np.asarray(m.get(path, []), dtype=dtype) for m in msgs]
        out[name] = np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
    return out, counts


def strings(values: np.ndarray) -> pa.Array:
    return pa.array(np.asarray(values, dtype=str), type=pa.string())


__all__ = [
    "BoolArray",
    "Columns",
    "ConvertContext",
    "Converter",
    "FloatArray",
    "IntArray",
    "NS_PER_S",
    "RoleRows",
    "all_finite",
    "explode",
    "f64",
    "list_array",
    "nullable",
    "ragged_list_array",
    "stamp_times",
    "strings",
]

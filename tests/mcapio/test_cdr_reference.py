"""Our CDR codec against the reference implementation, through its public API only.

For every message type the toolkit ships, random messages are written by ``mcap_ros2``'s public
MCAP writer (:class:`mcap_ros2.writer.Writer`, which serialises them with its own CDR encoder)
into an in-memory log, and the raw payloads are read back with ``mcap``'s reader. Then:

- our encoders (:func:`encode_batch`, :func:`encode_message`) write exactly those bytes;
- our decoder (:func:`decode_batch`) reads those bytes back to the values written.

The reverse direction (``mcap_ros2``'s public decoder reading what we encode) is checked in
``test_cdr.py``. Nothing here imports a private module of ``mcap_ros2``.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

from toolkit.mcapio.cdr import decode_batch
from toolkit.mcapio.cdr_encode import encode_batch, encode_message
from toolkit.mcapio.msgdefs import MessageSpec, known_types, load_msgdef, parse_msgdef

from .conftest import assert_columns_match, leaves, random_columns, row

ALL_TYPES = known_types()


def reference_payloads(type_name: str, messages: list[dict[str, Any]]) -> list[bytes]:
    """The CDR payloads ``mcap_ros2``'s public writer makes of ``messages`` (nested dicts)."""
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.NONE)
    schema = writer.register_msgdef(type_name, load_msgdef(type_name))
    for i, msg in enumerate(messages):
        writer.write_message("/t", schema, msg, log_time=i, publish_time=i)
    writer.finish()
    buf.seek(0)
    return [message.data for _, _, message in make_reader(buf).iter_messages()]


def reference_message(spec: MessageSpec, flat: Mapping[str, Any]) -> dict[str, Any]:
    """A row of columns (dotted keys, numpy values) as the reference writer takes a message:
    nested dicts of plain Python values, lists for arrays, ``bytes`` for uint8 arrays."""
    out: dict[str, Any] = {}
    for leaf in leaves(spec):
        node = out
        *parents, name = leaf.path.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        value = flat[leaf.path]
        f = leaf.field
        if f.nested is not None:  # array of messages
            assert f.is_array
            node[name] = [reference_message(f.nested, element) for element in value]
        elif f.is_string:
            node[name] = [str(v) for v in value] if f.is_array else str(value)
        elif f.is_array and f.type_name in ("uint8", "byte"):
            node[name] = np.asarray(value, dtype=np.uint8).tobytes()
        else:
            node[name] = np.asarray(value).tolist()
    return out


@pytest.mark.parametrize("type_name", ALL_TYPES)
@pytest.mark.parametrize("vary", [False, True], ids=["fixed-shape", "varying-shape"])
def test_codec_matches_the_reference_writer(
    type_name: str, vary: bool, rng: np.random.Generator
) -> None:
    spec = parse_msgdef(type_name)
    n = 7
    cols = random_columns(spec, n, rng, vary=vary)
    rows = [row(spec, cols, i) for i in range(n)]
    expected = reference_payloads(type_name, [reference_message(spec, r) for r in rows])
    assert len(expected) == n

    # encoding: the same bytes, from columns and from single messages
    assert encode_batch(type_name, cols) == expected
    for i in range(n):
        assert encode_message(type_name, rows[i]) == expected[i], f"message {i}"

    # decoding: the values the reference writer was given
    assert_columns_match(spec, decode_batch(type_name, expected), cols, n)
    by_text = decode_batch(type_name, expected, schema_text=load_msgdef(type_name))
    assert_columns_match(spec, by_text, cols, n)


def test_special_floats_and_defaults_match_the_reference_writer() -> None:
    """NaN, infinities, -0.0, subnormals and extreme integers; fields left to their defaults."""
    msg = {
        "header": {"stamp": {"sec": -(2**31), "nanosec": 2**32 - 1}, "frame_id": "é\x01"},
        "angle_min": float("nan"),
        "angle_max": float("-inf"),
        "range_min": -0.0,
        "range_max": 1e-45,
        "ranges": [float("inf"), 3.4e38, -1.5e-40],
    }
    (expected,) = reference_payloads("sensor_msgs/msg/LaserScan", [msg])
    assert encode_message("sensor_msgs/msg/LaserScan", msg) == expected
    flat = {
        "header.stamp.sec": -(2**31),
        "header.stamp.nanosec": 2**32 - 1,
        "header.frame_id": "é\x01",
        "angle_min": np.nan,
        "angle_max": -np.inf,
        "range_min": -0.0,
        "range_max": 1e-45,
        "ranges": np.array([np.inf, 3.4e38, -1.5e-40]),
    }
    assert encode_batch("sensor_msgs/msg/LaserScan", flat) == [expected]
    out = decode_batch("sensor_msgs/msg/LaserScan", [expected])
    assert np.isnan(out["angle_min"][0]) and out["angle_max"][0] == -np.inf
    assert np.signbit(out["range_min"][0]) and out["header.frame_id"][0] == "é\x01"

    # an empty message: every field takes its default (Quaternion.w = 1)
    for type_name in ("nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage"):
        (expected,) = reference_payloads(type_name, [{}])
        assert encode_message(type_name, {}) == expected
        assert encode_batch(type_name, {}) == [expected]

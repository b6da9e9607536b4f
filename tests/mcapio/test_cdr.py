"""CDR encoding and decoding: message definitions, layouts, both encoders, the decoder, errors.

What we encode is read back with ``mcap_ros2``'s public decoder; the other direction (our codec
against ``mcap_ros2``'s public writer) is in ``test_cdr_reference.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from toolkit.errors import CdrError, SchemaError
from toolkit.mcapio.cdr import decode_batch
from toolkit.mcapio.cdr_encode import encode_batch, encode_message
from toolkit.mcapio.cdr_layout import align, layout
from toolkit.mcapio.msgdefs import (
    SEPARATOR,
    known_types,
    load_msgdef,
    parse_msgdef,
    parse_schema_text,
)

from .conftest import (
    assert_columns_match,
    assert_object_matches,
    random_columns,
    reference_decoder,
    row,
)

WRITTEN_TYPES = [
    "builtin_interfaces/msg/Time",
    "std_msgs/msg/Header",
    "geometry_msgs/msg/Vector3",
    "geometry_msgs/msg/Quaternion",
    "geometry_msgs/msg/Point",
    "geometry_msgs/msg/Pose",
    "geometry_msgs/msg/PoseWithCovariance",
    "geometry_msgs/msg/Twist",
    "geometry_msgs/msg/TwistWithCovariance",
    "geometry_msgs/msg/Transform",
    "geometry_msgs/msg/TransformStamped",
    "geometry_msgs/msg/QuaternionStamped",
    "geometry_msgs/msg/TwistStamped",
    "sensor_msgs/msg/LaserScan",
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/NavSatFix",
    "sensor_msgs/msg/NavSatStatus",
    "sensor_msgs/msg/PointCloud2",
    "sensor_msgs/msg/PointField",
    "nav_msgs/msg/Odometry",
    "tf2_msgs/msg/TFMessage",
    "terrain_msgs/msg/GpsHeading",
    "terrain_msgs/msg/WheelSpeeds",
    "terrain_msgs/msg/RoughFeature",
    "terrain_msgs/msg/RoughFeatureArray",
]


# -- message definitions -----------------------------------------------------------------------


def test_every_written_type_ships() -> None:
    assert set(WRITTEN_TYPES) == set(known_types())


def test_msgdef_lists_each_dependency_once_in_depth_first_order() -> None:
    text = load_msgdef("nav_msgs/msg/Odometry")
    names = [line[5:] for line in text.splitlines() if line.startswith("MSG: ")]
    assert names == [
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose",
        "geometry_msgs/Point",
        "geometry_msgs/Quaternion",
        "geometry_msgs/TwistWithCovariance",
        "geometry_msgs/Twist",
        "geometry_msgs/Vector3",
    ]
    lines = text.splitlines()
    for k, line in enumerate(lines):
        if line.startswith("MSG: "):
            assert lines[k - 1] == SEPARATOR == "=" * 80
    assert load_msgdef("nav_msgs/Odometry") == text


def test_parsed_spec_has_real_ros2_fields() -> None:
    imu = parse_msgdef("sensor_msgs/msg/Imu")
    assert [f.name for f in imu.fields] == [
        "header",
        "orientation",
        "orientation_covariance",
        "angular_velocity",
        "angular_velocity_covariance",
        "linear_acceleration",
        "linear_acceleration_covariance",
    ]
    cov = imu.field("orientation_covariance")
    assert (cov.type_name, cov.is_array, cov.array_length, cov.is_primitive) == (
        "float64",
        True,
        9,
        True,
    )
    header = imu.field("header")
    assert header.nested is not None and header.nested.name == "std_msgs/msg/Header"
    stamp = header.nested.field("stamp")
    assert stamp.nested is not None
    assert [(f.name, f.type_name) for f in stamp.nested.fields] == [
        ("sec", "int32"),
        ("nanosec", "uint32"),
    ]
    ranges = parse_msgdef("sensor_msgs/msg/LaserScan").field("ranges")
    assert ranges.is_sequence and ranges.array_length is None
    assert parse_msgdef("sensor_msgs/msg/NavSatStatus").constant("STATUS_NO_FIX") == -1
    assert parse_msgdef("geometry_msgs/msg/Quaternion").field("w").default == 1.0


def test_schema_text_parses_to_the_same_spec() -> None:
    for name in WRITTEN_TYPES:
        assert parse_schema_text(name, load_msgdef(name)) == parse_msgdef(name)


def test_unknown_type_is_a_schema_error() -> None:
    with pytest.raises(SchemaError, match="no message definition"):
        load_msgdef("sensor_msgs/msg/PointCloud3")
    with pytest.raises(SchemaError, match="not a ROS 2 message type name"):
        parse_msgdef("LaserScan")


# -- encode_batch against the reference decoder -----------------------------------------------


@pytest.mark.parametrize("type_name", WRITTEN_TYPES)
@pytest.mark.parametrize("vary", [False, True], ids=["fixed-shape", "varying-shape"])
def test_encode_batch_decodes_with_reference(
    type_name: str, vary: bool, rng: np.random.Generator
) -> None:
    spec = parse_msgdef(type_name)
    n = 9
    cols = random_columns(spec, n, rng, vary=vary)
    payloads = encode_batch(type_name, cols)
    assert len(payloads) == n
    decode = reference_decoder(type_name)
    for i, payload in enumerate(payloads):
        assert payload[:4] == b"\x00\x01\x00\x00"
        assert_object_matches(spec, decode(payload), cols, i)
        # and byte for byte what the per-message encoder writes
        assert payload == encode_message(type_name, row(spec, cols, i))


@pytest.mark.parametrize("type_name", WRITTEN_TYPES)
@pytest.mark.parametrize("vary", [False, True], ids=["fixed-shape", "varying-shape"])
def test_decode_batch_of_per_message_payloads(
    type_name: str, vary: bool, rng: np.random.Generator
) -> None:
    spec = parse_msgdef(type_name)
    n = 11
    cols = random_columns(spec, n, rng, vary=vary)
    payloads = [encode_message(type_name, row(spec, cols, i)) for i in range(n)]
    assert_columns_match(spec, decode_batch(type_name, payloads), cols, n)
    # decoding by the schema text a log carries gives the same
    by_text = decode_batch(type_name, payloads, schema_text=load_msgdef(type_name))
    assert_columns_match(spec, by_text, cols, n)


def test_laser_scans_with_varying_frame_ids_and_beam_counts(rng: np.random.Generator) -> None:
    n = 200
    frames = np.array(["laser_a", "laser_bb", "l"])[rng.integers(0, 3, n)]
    beams = rng.choice([181, 181, 181, 90, 0], n)
    ranges = [rng.random(k).astype(np.float32) for k in beams]
    cols: dict[str, Any] = {"header.frame_id": frames, "ranges": ranges, "angle_min": -1.5}
    payloads = encode_batch("sensor_msgs/msg/LaserScan", cols)
    decode = reference_decoder("sensor_msgs/msg/LaserScan")
    out = decode_batch("sensor_msgs/msg/LaserScan", payloads)
    assert out["ranges"].dtype == object
    for i in range(n):
        msg = decode(payloads[i])
        assert msg.header.frame_id == frames[i] == out["header.frame_id"][i]
        np.testing.assert_array_equal(np.asarray(msg.ranges, np.float32), ranges[i])
        np.testing.assert_array_equal(out["ranges"][i], ranges[i])
    np.testing.assert_array_equal(out["angle_min"], np.float32(-1.5))


def test_uniform_batch_decodes_to_2d_columns(rng: np.random.Generator) -> None:
    n, beams = 50, 181
    ranges = rng.random((n, beams)).astype(np.float32)
    payloads = encode_batch(
        "sensor_msgs/msg/LaserScan",
        {"ranges": ranges, "header.stamp.sec": np.arange(n), "header.frame_id": "laser"},
    )
    assert len({len(p) for p in payloads}) == 1
    out = decode_batch("sensor_msgs/msg/LaserScan", payloads)
    assert out["ranges"].shape == (n, beams) and out["ranges"].dtype == np.float32
    np.testing.assert_array_equal(out["ranges"], ranges)
    assert out["intensities"].shape == (n, 0)
    assert out["header.stamp.sec"].dtype == np.int32
    assert out["header.frame_id"].dtype.kind == "U"


def test_broadcast_and_defaults() -> None:
    payloads = encode_batch(
        "sensor_msgs/msg/Imu",
        {"header.frame_id": "imu", "orientation_covariance": np.eye(3).ravel()},
        n=3,
    )
    assert len(payloads) == 3 and len(set(payloads)) == 1
    msg = reference_decoder("sensor_msgs/msg/Imu")(payloads[0])
    assert msg.orientation.w == 1.0  # the Quaternion default, as ROS 2 gives it
    assert msg.orientation_covariance == list(np.eye(3).ravel())
    assert encode_batch("terrain_msgs/msg/WheelSpeeds", {}) == [
        encode_message("terrain_msgs/msg/WheelSpeeds", {})
    ]
    assert encode_batch("sensor_msgs/msg/Imu", {"linear_acceleration.x": np.zeros(0)}) == []


def test_alignment_counts_from_the_end_of_the_header() -> None:
    assert [align(off, 8) for off in (4, 5, 11, 12, 13)] == [4, 12, 12, 12, 20]
    assert [align(off, 4) for off in (4, 5, 8, 9)] == [4, 8, 8, 12]
    assert [align(off, 2) for off in (5, 6)] == [6, 6]
    assert [align(off, 1) for off in (5, 6)] == [5, 6]


def test_layout_offsets_follow_cdr_alignment() -> None:
    spec = parse_msgdef("sensor_msgs/msg/LaserScan")
    dt = layout(spec, {"header.frame_id": 6, "ranges": 3, "intensities": 0})
    fields = dt.fields
    assert fields is not None
    assert fields["header.stamp.sec"][1] == 4
    assert fields["header.frame_id#n"][1] == 12
    assert fields["header.frame_id"][1] == 16  # 5 bytes + NUL at 21
    assert fields["header.frame_id#nul"][1] == 21
    assert fields["angle_min"][1] == 24  # aligned to 4 after the header
    assert fields["ranges#n"][1] == 52 and fields["ranges"][1] == 56
    assert "intensities" not in fields and fields["intensities#n"][1] == 68
    assert dt.itemsize == 72
    payload = encode_message(
        "sensor_msgs/msg/LaserScan", {"header": {"frame_id": "laser"}, "ranges": [1.0, 2.0, 3.0]}
    )
    assert len(payload) == dt.itemsize
    # float64 after an odd-length string is aligned to 8 from the end of the CDR header
    heading = layout(parse_msgdef("terrain_msgs/msg/GpsHeading"), {"header.frame_id": 2})
    assert heading.fields is not None and heading.fields["yaw"][1] == 4 + 16


def test_decode_tolerates_trailing_alignment_padding() -> None:
    payload = encode_message(
        "terrain_msgs/msg/GpsHeading", {"yaw": 0.5, "header": {"frame_id": "a"}}
    )
    out = decode_batch("terrain_msgs/msg/GpsHeading", [payload + b"\x00\x00\x00"])
    assert out["yaw"][0] == 0.5 and out["header.frame_id"][0] == "a"


# -- errors ------------------------------------------------------------------------------------


def _scan() -> bytes:
    return encode_message(
        "sensor_msgs/msg/LaserScan", {"header": {"frame_id": "laser"}, "ranges": [1.0] * 10}
    )


def test_truncated_payload_names_the_field() -> None:
    good = _scan()
    with pytest.raises(CdrError, match="payload 1 is truncated in field 'ranges'"):
        decode_batch("sensor_msgs/msg/LaserScan", [good, good[:60]])
    with pytest.raises(CdrError, match="truncated in field 'intensities'"):
        decode_batch("sensor_msgs/msg/LaserScan", [good[:-4]])
    with pytest.raises(CdrError, match="truncated in field 'header.frame_id'"):
        decode_batch("sensor_msgs/msg/LaserScan", [good[:14]])


def test_inconsistent_payloads_are_refused() -> None:
    good = _scan()
    huge = bytearray(good)
    huge[12:16] = (10_000).to_bytes(4, "little")  # frame_id length beyond the payload
    with pytest.raises(CdrError, match="header.frame_id"):
        decode_batch("sensor_msgs/msg/LaserScan", [good, bytes(huge)])
    with pytest.raises(CdrError, match="encapsulation 0000"):
        decode_batch("sensor_msgs/msg/LaserScan", [b"\x00\x00" + good[2:]])
    with pytest.raises(CdrError, match="unexpected bytes"):
        decode_batch("sensor_msgs/msg/LaserScan", [good + bytes(64)])
    no_nul = bytearray(good)
    no_nul[21] = ord("x")
    with pytest.raises(CdrError, match="not NUL-terminated"):
        decode_batch("sensor_msgs/msg/LaserScan", [bytes(no_nul)])
    with pytest.raises(CdrError, match="no CDR header"):
        decode_batch("sensor_msgs/msg/LaserScan", [b"\x00"])


def test_bad_columns_are_refused() -> None:
    with pytest.raises(CdrError, match="no field 'header.stamp.secs'"):
        encode_batch("sensor_msgs/msg/Imu", {"header.stamp.secs": 1})
    with pytest.raises(CdrError, match="out of range"):
        encode_batch("sensor_msgs/msg/NavSatFix", {"status.status": np.array([1, 300])})
    with pytest.raises(CdrError, match="floating-point"):
        encode_batch("sensor_msgs/msg/Imu", {"header.stamp.sec": np.array([1.5])})
    with pytest.raises(CdrError, match="has 3 rows, expected 2"):
        encode_batch(
            "terrain_msgs/msg/WheelSpeeds", {"front_left": np.zeros(2), "rear_left": np.zeros(3)}
        )
    with pytest.raises(CdrError, match=r"float64\[9\]"):
        encode_batch("sensor_msgs/msg/Imu", {"orientation_covariance": np.zeros((2, 4))})


def test_messages_with_nested_sequences_take_the_per_message_path() -> None:
    transforms = [
        [
            {
                "header": {"frame_id": "odom"},
                "child_frame_id": "base_link",
                "transform": {"translation": {"x": 1.0}},
            },
        ],
        [],
    ]
    payloads = encode_batch("tf2_msgs/msg/TFMessage", {"transforms": transforms})
    out = decode_batch("tf2_msgs/msg/TFMessage", payloads)
    first = out["transforms"][0]
    assert first["child_frame_id"].tolist() == ["base_link"]
    assert first["transform.translation.x"].tolist() == [1.0]
    assert first["transform.rotation.w"].tolist() == [1.0]
    assert len(out["transforms"][1]["child_frame_id"]) == 0


def test_encode_message_takes_nested_dotted_and_none_values() -> None:
    nested = {"header": {"stamp": {"sec": 3}, "frame_id": "gps"}, "yaw": 0.25}
    dotted = {"header.stamp.sec": 3, "header.frame_id": "gps", "yaw": np.float64(0.25)}
    mixed = {"header": {"frame_id": "gps"}, "header.stamp.sec": np.int32(3), "yaw_std": None}
    payload = encode_message("terrain_msgs/msg/GpsHeading", nested)
    assert encode_message("terrain_msgs/msg/GpsHeading", dotted) == payload
    assert encode_message("terrain_msgs/msg/GpsHeading", {**mixed, "yaw": 0.25}) == payload
    assert payload == encode_batch("terrain_msgs/msg/GpsHeading", dotted)[0]
    # None means "not given": the nested message keeps its defaults
    tf = encode_message("tf2_msgs/msg/TFMessage", {"transforms": [{"header": None}]})
    assert tf == encode_message("tf2_msgs/msg/TFMessage", {"transforms": [{}]})
    out = decode_batch("tf2_msgs/msg/TFMessage", [tf])
    assert out["transforms"][0]["transform.rotation.w"].tolist() == [1.0]


def test_encode_message_refuses_what_encode_batch_refuses() -> None:
    with pytest.raises(CdrError, match="no field 'header.stamp.secs'"):
        encode_message("sensor_msgs/msg/Imu", {"header": {"stamp": {"secs": 1}}})
    with pytest.raises(CdrError, match=r"no field 'transforms\[1\]\.child'"):
        encode_message("tf2_msgs/msg/TFMessage", {"transforms": [{}, {"child": "x"}]})
    with pytest.raises(CdrError, match="out of range"):
        encode_message("sensor_msgs/msg/NavSatFix", {"status": {"status": 300}})
    with pytest.raises(CdrError, match="floating-point"):
        encode_message("sensor_msgs/msg/Imu", {"header.stamp.sec": 1.5})
    with pytest.raises(CdrError, match=r"float64\[9\], got shape \(3,\)"):
        encode_message("sensor_msgs/msg/Imu", {"orientation_covariance": [1.0, 2.0, 3.0]})
    with pytest.raises(CdrError, match="expected str"):
        encode_message("sensor_msgs/msg/Imu", {"header.frame_id": 5})
    with pytest.raises(CdrError, match="is an array"):
        encode_message("tf2_msgs/msg/TFMessage", {"transforms": "odom"})
    with pytest.raises(CdrError, match="must be a mapping"):
        encode_message("tf2_msgs/msg/TFMessage", {"transforms": ["odom"]})

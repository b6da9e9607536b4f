"""PointCloud2 decoding: the CDR header, point layouts of five drivers, validity, point times.

Payloads are built here by :func:`encode_cloud` (struct.pack of the message's fields in either
byte order), itself checked against the toolkit's general encoder and ``mcap_ros2``'s decoder.
The same points are written in each driver's real point layout:

- ouster-ros (``PointOS``): x, y, z f32 at 0, 4, 8, 4 bytes of padding, intensity f32 16,
  t u32 20, reflectivity u16 24, ring u16 26, ambient u16 28, range u32 32; point_step 48;
- velodyne_pointcloud (ROS 2): x, y, z, intensity f32 at 0..12, ring u16 16, time f32 18;
  point_step 22 (time unaligned);
- nebula (``PointXYZIRCAEDT``, as tier4/nebula's docs/point_types.md lists it): x, y, z f32 at
  0..8, intensity u8 12, return_type u8 13, channel u16 14, azimuth f32 16, elevation f32 20,
  distance f32 24, time_stamp u32 28; point_step 32;
- livox_ros_driver2: x, y, z, intensity f32 at 0..12, tag u8 16, line u8 17, timestamp f64 18;
  point_step 26;
- rslidar (XYZIRT): x, y, z, intensity f32 at 0..12, ring u16 16, timestamp f64 18;
  point_step 26.
"""

from __future__ import annotations

import pickle
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from toolkit.errors import CdrError, CloudLayoutError, CloudPayloadError
from toolkit.mcapio.cdr_encode import encode_message
from toolkit.mcapio.pointcloud2 import (
    PRESETS,
    Cloud,
    PointField,
    PointTime,
    cloud_dtype,
    cloud_points,
    parse_cloud,
    point_times_ns,
    preset_for_fields,
    xyz_valid,
)

from .conftest import reference_decoder

TOPIC = "/lidar/points"
F32, F64, U8, U16, U32 = 7, 8, 2, 4, 6

#: Per driver: fields (name, offset, datatype), point_step.
LAYOUTS: dict[str, tuple[list[tuple[str, int, int]], int]] = {
    "ouster": (
        [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 16, F32), ("t", 20, U32),
         ("reflectivity", 24, U16), ("ring", 26, U16), ("ambient", 28, U16), ("range", 32, U32)],
        48,
    ),
    "velodyne": (
        [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, F32), ("ring", 16, U16),
         ("time", 18, F32)],
        22,
    ),
    "nebula": (
        [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, U8),
         ("return_type", 13, U8), ("channel", 14, U16), ("azimuth", 16, F32),
         ("elevation", 20, F32), ("distance", 24, F32), ("time_stamp", 28, U32)],
        32,
    ),
    "livox": (
        [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, F32), ("tag", 16, U8),
         ("line", 17, U8), ("timestamp", 18, F64)],
        26,
    ),
    "rslidar": (
        [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, F32), ("ring", 16, U16),
         ("timestamp", 18, F64)],
        26,
    ),
}  # fmt: skip
NP_KIND = {F32: "f4", F64: "f8", U8: "u1", U16: "u2", U32: "u4"}

STAMP_NS = 1_700_000_000_123_456_789  # the sweep's start
SWEEP_NS = 100_000_000


def encode_cloud(
    fields: Sequence[tuple[str, int, int] | tuple[str, int, int, int]],
    point_step: int,
    data: bytes,
    *,
    height: int = 1,
    width: int | None = None,
    row_step: int | None = None,
    stamp_ns: int = STAMP_NS,
    frame_id: str = "os_sensor",
    big_endian: bool = False,
    is_dense: bool = True,
) -> bytes:
    """A PointCloud2 CDR payload (the given byte order for the CDR and for the points' flag)."""
    o = ">" if big_endian else "<"
    out = bytearray(b"\x00\x00\x00\x00" if big_endian else b"\x00\x01\x00\x00")

    def pad(size: int) -> None:
        out.extend(bytes(-(len(out) - 4) % size))

    def u32(v: int) -> None:
        pad(4)
        out.extend(struct.pack(o + "I", v))

    def string(s: str) -> None:
        raw = s.encode()
        u32(len(raw) + 1)
        out.extend(raw + b"\x00")

    if width is None:
        width = len(data) // point_step // height
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    out.extend(struct.pack(o + "iI", sec, nanosec))
    string(frame_id)
    u32(height)
    u32(width)
    u32(len(fields))
    for f in fields:
        string(f[0])
        u32(f[1])
        out.append(f[2])
        u32(f[3] if len(f) == 4 else 1)
    out.append(int(big_endian))
    u32(point_step)
    u32(width * point_step if row_step is None else row_step)
    u32(len(data))
    out.extend(data)
    out.append(int(is_dense))
    return bytes(out)


def truth(n: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points: xyz float32 ``(n, 3)`` and their true times, int64 ns ``(n,)``."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-50, 50, (n, 3)).astype(np.float32)
    t_ns = STAMP_NS + np.sort(rng.integers(0, SWEEP_NS, n))
    return xyz, t_ns


def point_bytes(driver: str, xyz: np.ndarray, t_ns: np.ndarray, stamp_ns: int,
                big_endian: bool = False) -> bytes:  # fmt: skip
    """The points in ``driver``'s layout, time in its unit and reference."""
    fields, step = LAYOUTS[driver]
    o = ">" if big_endian else "<"
    dt = np.dtype({"names": [f[0] for f in fields],
                   "formats": [o + NP_KIND[f[2]] for f in fields],
                   "offsets": [f[1] for f in fields], "itemsize": step})  # fmt: skip
    arr = np.zeros(len(xyz), dtype=dt)
    arr["x"], arr["y"], arr["z"] = xyz.T
    spec = PRESETS[driver]
    if spec.reference == "header":
        rel = t_ns - stamp_ns
        arr[spec.field] = rel / 1e9 if spec.unit == "s" else rel
    elif spec.unit == "s":
        arr[spec.field] = t_ns / 1e9
    else:
        arr[spec.field] = t_ns.astype(np.float64)
    if "ring" in arr.dtype.names:
        arr["ring"] = np.arange(len(xyz)) % 16
    return arr.tobytes()


def driver_payload(driver: str, xyz: np.ndarray, t_ns: np.ndarray,
                   big_endian: bool = False, **kw: Any) -> bytes:  # fmt: skip
    # velodyne_pointcloud stamps the header at the sweep's end; the others at its start.
    stamp = STAMP_NS + SWEEP_NS if PRESETS[driver].header_at == "end" else STAMP_NS
    fields, step = LAYOUTS[driver]
    data = point_bytes(driver, xyz, t_ns, stamp, big_endian)
    return encode_cloud(fields, step, data, stamp_ns=stamp, big_endian=big_endian, **kw)


def decode(payload: bytes, spec: PointTime | None = None) -> tuple[Cloud, np.ndarray, Any]:
    cloud = parse_cloud(payload, topic=TOPIC)
    points = cloud_points(
        cloud, cloud_dtype(cloud.fields, cloud.point_step, cloud.is_bigendian, topic=TOPIC)
    )
    if spec is None:
        spec = PRESETS[preset_for_fields(points.dtype.names or ())]
    return cloud, points, point_times_ns(points, cloud.stamp_ns, spec, topic=TOPIC)


# --------------------------------------------------------------------------------------------


def test_the_helper_writes_what_the_house_encoder_writes_and_mcap_ros2_reads() -> None:
    xyz, t_ns = truth(5)
    payload = driver_payload("ouster", xyz, t_ns)
    fields, step = LAYOUTS["ouster"]
    msg = {
        "header": {"stamp": {"sec": STAMP_NS // 10**9, "nanosec": STAMP_NS % 10**9},
                   "frame_id": "os_sensor"},
        "height": 1, "width": 5,
        "fields": [{"name": n, "offset": o, "datatype": d, "count": 1} for n, o, d in fields],
        "is_bigendian": False, "point_step": step, "row_step": 5 * step,
        "data": np.frombuffer(payload[-(5 * step) - 1 : -1], np.uint8), "is_dense": True,
    }  # fmt: skip
    assert encode_message("sensor_msgs/msg/PointCloud2", msg) == payload
    ref = reference_decoder("sensor_msgs/msg/PointCloud2")(payload)
    cloud = parse_cloud(payload, topic=TOPIC)
    assert cloud.stamp_ns == ref.header.stamp.sec * 10**9 + ref.header.stamp.nanosec
    assert cloud.frame_id == ref.header.frame_id == "os_sensor"
    assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step) == (
        ref.height, ref.width, ref.point_step, ref.row_step)  # fmt: skip
    assert cloud.fields == tuple(
        PointField(f.name, f.offset, f.datatype, f.count) for f in ref.fields
    )
    assert bytes(cloud.data) == bytes(ref.data)
    assert cloud.is_dense is True and cloud.is_bigendian is False


@pytest.mark.parametrize("big_endian", [False, True])
def test_every_driver_layout_decodes_to_the_same_points_and_times(big_endian: bool) -> None:
    xyz, t_ns = truth()
    for driver in LAYOUTS:
        cloud, points, times = decode(driver_payload(driver, xyz, t_ns, big_endian))
        assert cloud.is_bigendian is big_endian
        assert preset_for_fields(points.dtype.names or ()) == driver
        got, keep, counts = xyz_valid(points)
        assert got.dtype == np.float32 and keep.all() and counts.kept == len(xyz)
        np.testing.assert_array_equal(got, xyz, err_msg=driver)
        if driver in ("ouster", "nebula"):  # integer ns: exact
            np.testing.assert_array_equal(times, t_ns, err_msg=driver)
        elif driver == "livox":  # float64 ns near 1.7e18: a multiple of 256 ns, rounded
            assert np.abs(times - t_ns).max() <= 128, driver
        else:  # float seconds: to 1 us
            assert np.abs(times - t_ns).max() <= 1000, driver


def test_velodyne_times_are_negative_offsets_from_a_header_at_the_sweep_end() -> None:
    xyz, t_ns = truth()
    cloud, points, times = decode(driver_payload("velodyne", xyz, t_ns))
    assert cloud.stamp_ns == STAMP_NS + SWEEP_NS
    assert (points["time"] <= 0).all()
    assert (times <= cloud.stamp_ns).all()
    assert PRESETS["velodyne"].header_at == "end"


def test_integer_and_representable_float_times_are_exact() -> None:
    # A livox time that float64 holds exactly comes back exactly: nothing is added to it.
    t_ns = np.array([1_700_000_000_000_000_000, 1_700_000_000_000_000_256], dtype=np.int64)
    xyz = np.ones((2, 3), np.float32)
    _, _, times = decode(driver_payload("livox", xyz, t_ns))
    np.testing.assert_array_equal(times, t_ns)
    # rslidar seconds: the nanosecond nearest to the float64 value, not float64(value * 1e9).
    _, points, times = decode(driver_payload("rslidar", xyz, t_ns))
    value = points["timestamp"].astype(np.float64)
    whole = np.floor(value)
    exact = whole.astype(np.int64) * 10**9 + np.rint((value - whole) * 1e9).astype(np.int64)
    np.testing.assert_array_equal(times, exact)


def test_times_by_hand_and_without_a_field() -> None:
    xyz, t_ns = truth(8)
    _, points, _ = decode(driver_payload("ouster", xyz, t_ns))
    none = point_times_ns(points, 42, PRESETS["none"], topic=TOPIC)
    np.testing.assert_array_equal(none, np.full(8, 42))
    keep = np.arange(8) % 2 == 0
    np.testing.assert_array_equal(
        point_times_ns(points, 42, PRESETS["none"], topic=TOPIC, keep=keep), np.full(4, 42)
    )
    us = point_times_ns(points, 0, PointTime("ring", "us"), topic=TOPIC)
    np.testing.assert_array_equal(us, points["ring"].astype(np.int64) * 1000)
    with pytest.raises(CloudLayoutError, match=f"topic {TOPIC}: no time field 'time'"):
        point_times_ns(points, 0, PRESETS["velodyne"], topic=TOPIC)


def test_non_finite_float_times_are_refused() -> None:
    xyz, t_ns = truth(4)
    fields, step = LAYOUTS["velodyne"]
    arr = np.frombuffer(point_bytes("velodyne", xyz, t_ns, STAMP_NS), np.uint8).copy()
    arr[18 : 18 + 4] = np.frombuffer(np.float32(np.nan).tobytes(), np.uint8)
    with pytest.raises(
        CloudPayloadError, match="1 values of 'time' are not finite or out of range"
    ):
        decode(encode_cloud(fields, step, arr.tobytes()))


def test_float_times_beyond_int64_are_refused() -> None:
    fields = [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("timestamp", 12, F64)]
    dt = np.dtype({"names": ["x", "y", "z", "timestamp"], "formats": ["<f4"] * 3 + ["<f8"],
                   "offsets": [0, 4, 8, 12], "itemsize": 20})  # fmt: skip
    arr = np.ones(2, dt)
    arr["timestamp"] = [1.7e9, 1e12]  # seconds: the second is 31,700 years away
    _, points, _ = decode(encode_cloud(fields, 20, arr.tobytes()), PRESETS["none"])
    with pytest.raises(CloudPayloadError, match="1 values of 'timestamp' are not finite or out"):
        point_times_ns(points, 0, PRESETS["rslidar"], topic=TOPIC)


def test_preset_detection_from_field_names() -> None:
    assert preset_for_fields(["x", "y", "z", "intensity", "t", "reflectivity", "ring"]) == "ouster"
    assert preset_for_fields(["x", "y", "z", "t", "ring"]) == "ouster"
    assert preset_for_fields(["x", "y", "z", "ring", "time"]) == "velodyne"
    assert preset_for_fields(["x", "y", "z", "channel", "time_stamp"]) == "nebula"
    assert preset_for_fields(["x", "y", "z", "line", "tag", "timestamp"]) == "livox"
    assert preset_for_fields(["x", "y", "z", "ring", "timestamp"]) == "rslidar"
    assert preset_for_fields(["x", "y", "z", "rgb"]) == "none"
    assert preset_for_fields(iter(["x", "y", "z", "t"])) == "none"  # t without ring
    assert set(PRESETS) == {"ouster", "velodyne", "nebula", "livox", "rslidar", "none"}


def test_organised_cloud_with_padded_rows() -> None:
    height, width = 4, 5
    xyz, t_ns = truth(height * width)
    fields, step = LAYOUTS["ouster"]
    raw = point_bytes("ouster", xyz, t_ns, STAMP_NS)
    row_step = width * step + 16
    rows = b"".join(
        raw[r * width * step : (r + 1) * width * step] + b"\xee" * 16 for r in range(height)
    )
    payload = encode_cloud(fields, step, rows + b"trailing", height=height, width=width,
                           row_step=row_step)  # fmt: skip
    cloud, points, times = decode(payload)
    assert points.shape == (height * width,)
    got, keep, _ = xyz_valid(points)
    np.testing.assert_array_equal(got, xyz)
    np.testing.assert_array_equal(times, t_ns)
    # Unpadded organised rows stay a view.
    payload = encode_cloud(fields, step, raw, height=height, width=width)
    _, points, _ = decode(payload)
    assert np.shares_memory(points, np.frombuffer(payload, np.uint8))


def test_points_are_a_view_of_the_payload() -> None:
    xyz, t_ns = truth()
    for driver in LAYOUTS:
        payload = driver_payload(driver, xyz, t_ns)
        cloud, points, _ = decode(payload)
        buf = np.frombuffer(payload, np.uint8)
        assert np.shares_memory(np.frombuffer(cloud.data, np.uint8), buf)
        assert np.shares_memory(points, buf), driver


def test_nan_and_zero_points_are_dropped_and_counted_whatever_is_dense_says() -> None:
    xyz, t_ns = truth(10)
    xyz[1] = [np.nan, 1, 2]
    xyz[4] = [1, np.inf, 2]
    xyz[5] = 0.0
    xyz[7] = [-0.0, 0.0, 0.0]
    xyz[8] = [0.0, 0.0, 1.0]  # on an axis, not at the origin: kept
    for driver in ("ouster", "velodyne"):
        cloud, points, times = decode(driver_payload(driver, xyz, t_ns, is_dense=True))
        assert cloud.is_dense is True  # the driver's claim, which is false
        got, keep, counts = xyz_valid(points)
        assert (counts.total, counts.non_finite, counts.zero_range, counts.kept) == (10, 2, 2, 6)
        np.testing.assert_array_equal(keep, ~np.isin(np.arange(10), [1, 4, 5, 7]))
        np.testing.assert_array_equal(got, xyz[keep])
        kept = point_times_ns(points, cloud.stamp_ns, PRESETS[driver], topic=TOPIC, keep=keep)
        np.testing.assert_array_equal(kept, times[keep])


def test_times_of_dropped_points_may_be_nan_when_keep_is_given() -> None:
    xyz, t_ns = truth(4)
    xyz[2] = np.nan
    fields, step = LAYOUTS["velodyne"]
    arr = np.frombuffer(point_bytes("velodyne", xyz, t_ns, STAMP_NS), np.uint8).copy()
    arr[2 * step + 18 : 2 * step + 22] = np.frombuffer(np.float32(np.nan).tobytes(), np.uint8)
    cloud = parse_cloud(encode_cloud(fields, step, arr.tobytes()), topic=TOPIC)
    points = cloud_points(cloud, cloud_dtype(cloud.fields, step, False, topic=TOPIC))
    _, keep, _ = xyz_valid(points)
    times = point_times_ns(points, STAMP_NS, PRESETS["velodyne"], topic=TOPIC, keep=keep)
    assert np.abs(times - t_ns[keep]).max() <= 1000
    with pytest.raises(
        CloudPayloadError, match="1 values of 'time' are not finite or out of range"
    ):
        point_times_ns(points, STAMP_NS, PRESETS["velodyne"], topic=TOPIC)


def test_float64_positions_stay_float64() -> None:
    fields = [("x", 0, F64), ("y", 8, F64), ("z", 16, F64)]
    xyz = np.array([[1.0, 2.0, 3.0], [0.1, 0.2, 1e-300]])
    cloud, points, _ = decode(encode_cloud(fields, 24, xyz.tobytes()))
    got, _, _ = xyz_valid(points)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, xyz)


def test_extreme_but_finite_coordinates_are_kept() -> None:
    tiny, huge = np.float32(1e-45), np.float32(3e38)  # a subnormal and near float32's max
    xyz = np.array([[tiny, 0, 0], [huge, huge, -huge], [0, -0.0, tiny], [0, 0, 0]], np.float32)
    fields = [("x", 0, F32), ("y", 4, F32), ("z", 8, F32)]
    for big_endian in (False, True):
        data = xyz.astype(">f4" if big_endian else "<f4").tobytes()
        _, points, _ = decode(encode_cloud(fields, 12, data, big_endian=big_endian))
        got, keep, counts = xyz_valid(points)
        np.testing.assert_array_equal(keep, [True, True, True, False])
        np.testing.assert_array_equal(got, xyz[:3])
        assert got.dtype == np.dtype("=f4") and counts.zero_range == 1


def test_integer_positions_become_float64() -> None:
    fields = [("x", 0, 5), ("y", 4, 5), ("z", 8, 3)]  # int32, int32, int16 (then 2 bytes pad)
    dt = np.dtype({"names": ["x", "y", "z"], "formats": ["<i4", "<i4", "<i2"],
                   "offsets": [0, 4, 8], "itemsize": 12})  # fmt: skip
    arr = np.zeros(3, dt)
    arr["x"], arr["y"], arr["z"] = [1, 0, -2_000_000_000], [2, 0, 5], [3, 0, -7]
    _, points, _ = decode(encode_cloud(fields, 12, arr.tobytes()))
    got, keep, counts = xyz_valid(points)
    assert got.dtype == np.float64 and counts.zero_range == 1
    np.testing.assert_array_equal(got, [[1, 2, 3], [-2_000_000_000, 5, -7]])


def test_count_zero_is_one_and_count_above_one_is_a_subarray() -> None:
    fields = [("x", 0, F32, 0), ("y", 4, F32, 1), ("z", 8, F32, 1), ("normal", 12, F32, 3)]
    dt = cloud_dtype([PointField(*f) for f in fields], 24, False, topic=TOPIC)
    assert dt["x"] == np.dtype("<f4") and dt["normal"].shape == (3,)
    assert dt.itemsize == 24


def test_dtypes_are_cached_per_layout() -> None:
    fields = tuple(PointField(n, o, d, 1) for n, o, d in LAYOUTS["velodyne"][0])
    a = cloud_dtype(fields, 22, False, topic="a")
    assert cloud_dtype(list(fields), 22, False, topic="b") is a
    assert cloud_dtype(fields, 22, True, topic="a") is not a
    assert a.fields is not None and a.fields["time"][1] == 18


def _fields(*spec: tuple[str, int, int, int]) -> list[PointField]:
    return [PointField(*f) for f in spec]


XYZ = [("x", 0, F32, 1), ("y", 4, F32, 1), ("z", 8, F32, 1)]


@pytest.mark.parametrize(
    ("fields", "step", "problem"),
    [
        (XYZ + [("i", 10, F32, 1)], 16, "fields 'z' and 'i' overlap"),
        (XYZ + [("i", 12, F32, 2)], 16, "field 'i' at offset 12 (8 bytes) runs past point_step 16"),
        (XYZ + [("i", 12, 9, 1)], 16, "field 'i' has unknown datatype 9"),
        (XYZ + [("i", 12, 0, 1)], 16, "field 'i' has unknown datatype 0"),
        (XYZ[:2], 12, "no field 'z'"),
        (XYZ + [("y", 12, F32, 1)], 16, "field 'y' appears twice"),
        (XYZ, 0, "point_step is 0"),
        (XYZ + [("", 12, F32, 1)], 16, "empty name"),
        ([("x", 0, F32, 2), ("y", 8, F32, 1), ("z", 12, F32, 1)], 16, "field 'x' has count > 1"),
    ],
)
def test_refused_layouts_name_the_topic(
    fields: list[tuple[str, int, int, int]], step: int, problem: str
) -> None:
    with pytest.raises(CloudLayoutError) as info:
        cloud_dtype(_fields(*fields), step, False, topic="/os_cloud_node/points")
    assert str(info.value).startswith("topic /os_cloud_node/points: ")
    assert problem in str(info.value) and "\n" not in str(info.value)
    assert info.value.topic == "/os_cloud_node/points" and problem in info.value.problem
    assert isinstance(info.value, CdrError)


def test_the_example_message_of_the_brief() -> None:
    with pytest.raises(CloudLayoutError) as info:
        cloud_dtype(_fields(("x", 44, F32, 1), *XYZ[1:]), 46, False, topic="/os_cloud_node/points")
    assert str(info.value) == (
        "topic /os_cloud_node/points: field 'x' at offset 44 (4 bytes) runs past point_step 46"
    )


def test_steps_that_do_not_fit_the_data_are_refused() -> None:
    fields = [f[:3] for f in XYZ]
    data = bytes(12 * 6)
    with pytest.raises(CloudLayoutError, match="row_step 30 is shorter than width 3"):
        decode(encode_cloud(fields, 12, data, height=2, width=3, row_step=30))
    with pytest.raises(
        CloudLayoutError, match=r"data has 72 bytes, fewer than height 2 x row_step 40"
    ):
        decode(encode_cloud(fields, 12, data, height=2, width=3, row_step=40))
    with pytest.raises(CloudLayoutError, match="fewer than height 4"):
        decode(encode_cloud(fields, 12, data, height=4, width=3))


def test_truncated_and_inconsistent_payloads_are_refused() -> None:
    xyz, t_ns = truth(4)
    payload = driver_payload("ouster", xyz, t_ns)
    for cut in (0, 3, 10, 20, 60, 200, len(payload) - 1 - 4 * 48, len(payload) - 1):
        with pytest.raises(CloudPayloadError, match=f"topic {TOPIC}: .*(truncated|no CDR)"):
            parse_cloud(payload[:cut], topic=TOPIC)
    with pytest.raises(CloudPayloadError, match="encapsulation 0002"):
        parse_cloud(b"\x00\x02" + payload[2:], topic=TOPIC)
    with pytest.raises(CloudPayloadError, match="unexpected bytes after is_dense"):
        parse_cloud(payload + bytes(8), topic=TOPIC)
    parse_cloud(payload + bytes(3), topic=TOPIC)  # DDS padding is fine
    with pytest.raises(CloudPayloadError, match="is_dense is 7"):
        parse_cloud(payload[:-1] + b"\x07", topic=TOPIC)
    bad = bytearray(payload)
    bad[16 + len("os_sensor")] = ord("!")  # the frame_id's NUL
    with pytest.raises(CloudPayloadError, match="header.frame_id is not NUL-terminated"):
        parse_cloud(bytes(bad), topic=TOPIC)


def test_errors_survive_pickling() -> None:
    err = CloudLayoutError("/t", "point_step is 0")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is CloudLayoutError and str(back) == str(err) and back.problem == err.problem


def test_memoryview_payload_and_empty_cloud() -> None:
    fields = [f[:3] for f in XYZ]
    payload = encode_cloud(fields, 12, b"", height=0, width=0)
    cloud, points, times = decode(memoryview(bytearray(payload)))
    assert points.shape == (0,) and times.shape == (0,)
    got, keep, counts = xyz_valid(points)
    assert got.shape == (0, 3) and counts.total == 0

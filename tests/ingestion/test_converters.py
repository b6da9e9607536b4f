"""Converters against hand-built messages: values, units, time correction, masks.

Messages are encoded with the toolkit's CDR encoder and decoded with ``decode_batch``, so each
converter sees exactly the columns ingest hands it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from scipy.spatial.transform import Rotation

from toolkit.geometry.rotations import euler_rates_zyx
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.ingestion.rows import ConvertContext, RoleRows
from toolkit.mcapio.cdr import decode_batch
from toolkit.mcapio.cdr_encode import encode_batch, encode_message
from toolkit.mcapio.cdr_layout import plan_for
from toolkit.tableio import conform_table, load_table_schema

SEC = 1_128_783_600


def header(stamp_ns: np.ndarray, frame: str = "base_link") -> dict[str, Any]:
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    return {
        "header.stamp.sec": (stamp_ns // 1_000_000_000).astype(np.int32),
        "header.stamp.nanosec": (stamp_ns % 1_000_000_000).astype(np.uint32),
        "header.frame_id": frame,
    }


def convert(
    role: str,
    type_name: str,
    cols: dict[str, Any],
    *,
    log_time_ns: np.ndarray | None = None,
    topic: str = "/t",
    correction_ns: int = 0,
) -> RoleRows:
    payloads = encode_batch(type_name, cols)
    decoded = decode_batch(type_name, payloads)
    stamps = (
        decoded["header.stamp.sec"].astype(np.int64) * 1_000_000_000
        + decoded["header.stamp.nanosec"]
    )
    log_t = stamps if log_time_ns is None else np.asarray(log_time_ns, dtype=np.int64)
    ctx = ConvertContext(topic, role, type_name, correction_ns)
    rows = ROLE_SPECS[role].converter_for(topic, type_name)(decoded, log_t, ctx)
    table_name = ROLE_SPECS[role].table
    if table_name not in ("truth_features", "tf_static"):
        conform_table(rows.table, load_table_schema(table_name))  # schema-valid rows
    return rows


def col(rows: RoleRows, name: str) -> list[Any]:
    return list(rows.table.column(name).to_pylist())


def test_time_is_stamp_corrected_by_offset_and_latency() -> None:
    stamps = np.array([SEC * 10**9 + 5, SEC * 10**9 + 999_999_999], dtype=np.int64)
    cols = {**header(stamps), "linear_acceleration.z": [9.8, 9.7]}
    rows = convert("imu", "sensor_msgs/msg/Imu", cols, correction_ns=-2_500_000)
    assert col(rows, "t_ns") == (stamps - 2_500_000).tolist()
    assert rows.table.schema.field("t_ns").type == pa.int64()


def test_zero_stamp_takes_log_time() -> None:
    cols = {**header(np.array([0, SEC * 10**9])), "linear_acceleration.z": [1.0, 2.0]}
    log_t = np.array([SEC * 10**9 + 7, SEC * 10**9 + 8])
    rows = convert("imu", "sensor_msgs/msg/Imu", cols, log_time_ns=log_t, correction_ns=100)
    assert col(rows, "t_ns") == [SEC * 10**9 + 7, SEC * 10**9 + 100]
    assert rows.stamp_missing.tolist() == [True, False]


def test_imu_values_and_non_finite_mask() -> None:
    stamps = SEC * 10**9 + np.arange(3) * 10_000_000
    cols = {
        **header(stamps, "imu_link"),
        "linear_acceleration.x": [0.1, 0.2, 0.3],
        "linear_acceleration.y": [-0.1, np.nan, 0.0],
        "linear_acceleration.z": [9.81, 9.80, 9.79],
        "angular_velocity.x": [0.01, 0.02, np.inf],
        "angular_velocity.y": [0.0, 0.0, 0.0],
        "angular_velocity.z": [-0.5, 0.5, 0.0],
    }
    rows = convert("imu", "sensor_msgs/msg/Imu", cols)
    assert col(rows, "accel_x") == [0.1, 0.2, 0.3]
    assert col(rows, "accel_z") == [9.81, 9.80, 9.79]
    assert col(rows, "gyro_z") == [-0.5, 0.5, 0.0]
    assert rows.finite.tolist() == [True, False, False]


def test_imu_reported_orientation_kept_only_when_given() -> None:
    """REP 145: covariance[0] = -1 means no orientation; all-zero covariance is unknown."""
    stamps = SEC * 10**9 + np.arange(4) * 10_000_000
    cov = np.zeros((4, 9))
    cov[0, [0, 4, 8]] = 0.01  # given, with its covariance
    cov[1, 0] = -1.0  # no orientation
    # row 2: zero covariance (unknown); row 3: a zero quaternion (nothing to use)
    cols = {
        **header(stamps, "imu_link"),
        "linear_acceleration.z": [9.8] * 4,
        "orientation.x": [0.0, 0.5, 0.0, 0.0],
        "orientation.y": [0.0, 0.5, 0.0, 0.0],
        "orientation.z": [0.6, 0.5, 0.0, 0.0],
        "orientation.w": [0.8, 0.5, 2.0, 0.0],
        "orientation_covariance": cov,
    }
    rows = convert("imu", "sensor_msgs/msg/Imu", cols)
    assert col(rows, "orientation_z") == [0.6, None, 0.0, None]
    assert col(rows, "orientation_w") == [0.8, None, 1.0, None]  # normalised
    assert col(rows, "orientation_covariance") == [[0.01, 0.01, 0.01], None, None, None]
    assert rows.finite.all()  # a missing orientation does not reject the sample


def test_gps_values_status_covariance_and_no_fix() -> None:
    stamps = SEC * 10**9 + np.arange(3) * 100_000_000
    cov = np.zeros((3, 9))
    cov[:, 0], cov[:, 4], cov[:, 8] = 0.25, 0.36, 1.0
    cols = {
        **header(stamps, "gps_antenna"),
        "status.status": np.array([2, -1, 0], dtype=np.int8),
        "latitude": [37.1, np.nan, np.nan],
        "longitude": [-116.2, np.nan, -116.3],
        "altitude": [900.0, np.nan, 901.0],
        "position_covariance": cov,
        "position_covariance_type": np.array([2, 0, 2], dtype=np.uint8),
    }
    rows = convert("gps", "sensor_msgs/msg/NavSatFix", cols)
    assert col(rows, "latitude")[0] == 37.1
    assert col(rows, "status") == [2, -1, 0]
    assert col(rows, "position_covariance") == [[0.25, 0.36, 1.0], None, [0.25, 0.36, 1.0]]
    # NO_FIX with NaN is kept (the pose stage decides); a "fix" with NaN is not finite.
    assert rows.finite.tolist() == [True, True, False]
    assert rows.counts["gps_no_fix"].tolist() == [0, 1, 0]


def test_heading_from_gps_heading() -> None:
    stamps = SEC * 10**9 + np.arange(3) * 100_000_000
    cols = {**header(stamps), "yaw": [0.5, -3.0, np.nan], "yaw_std": [0.01, np.nan, 0.02]}
    rows = convert("heading", "terrain_msgs/msg/GpsHeading", cols)
    assert col(rows, "yaw")[:2] == [0.5, -3.0]
    assert col(rows, "yaw_std")[:2] == [0.01, None]
    assert rows.finite.tolist() == [True, True, False]


def test_heading_from_quaternion_stamped() -> None:
    yaw = np.array([0.0, 0.7, -2.5, math.pi / 2])
    roll = np.array([0.1, -0.05, 0.2, 0.0])
    pitch = np.array([0.05, 0.1, -0.15, 0.0])
    quat = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=1)).as_quat()
    quat[1] *= 3.0  # not normalised: still the same rotation
    cols = {
        **header(SEC * 10**9 + np.arange(4)),
        "quaternion.x": quat[:, 0],
        "quaternion.y": quat[:, 1],
        "quaternion.z": quat[:, 2],
        "quaternion.w": quat[:, 3],
    }
    rows = convert("heading", "geometry_msgs/msg/QuaternionStamped", cols)
    np.testing.assert_allclose(col(rows, "yaw"), yaw, atol=1e-12)
    assert col(rows, "yaw_std") == [None] * 4  # no uncertainty in the message: unknown
    assert rows.finite.all()


def test_heading_from_zero_quaternion_is_not_finite() -> None:
    cols = {**header(np.array([SEC * 10**9])), "quaternion.w": [0.0]}
    rows = convert("heading", "geometry_msgs/msg/QuaternionStamped", cols)
    assert rows.finite.tolist() == [False]


def test_wheels_from_wheel_speeds_rear_mean() -> None:
    cols = {
        **header(SEC * 10**9 + np.arange(3)),
        "front_left": [5.1, 0.0, np.nan],
        "front_right": [5.3, 0.0, 4.0],
        "rear_left": [4.9, 0.0, 4.0],
        "rear_right": [5.1, 0.0, np.nan],
    }
    rows = convert("wheels", "terrain_msgs/msg/WheelSpeeds", cols)
    assert col(rows, "speed")[:2] == [5.0, 0.0]  # zero speed is fine
    assert col(rows, "front_left")[:2] == [5.1, 0.0]
    assert col(rows, "front_left")[2] is None  # a bad front wheel is null ...
    assert rows.finite.tolist() == [True, True, False]  # ... a bad rear wheel rejects


@pytest.mark.parametrize(
    ("type_name", "path"),
    [
        ("geometry_msgs/msg/TwistStamped", "twist.linear.x"),
        ("nav_msgs/msg/Odometry", "twist.twist.linear.x"),
    ],
)
def test_wheels_from_twist_and_odometry(type_name: str, path: str) -> None:
    cols = {**header(SEC * 10**9 + np.arange(3)), path: [3.5, 0.0, -1.0]}
    rows = convert("wheels", type_name, cols)
    assert col(rows, "speed") == [3.5, 0.0, -1.0]
    for wheel in ("front_left", "front_right", "rear_left", "rear_right"):
        assert col(rows, wheel) == [None, None, None]
    assert rows.finite.all()


def _scan_cols(n: int, beams: int, fov_rad: float) -> dict[str, Any]:
    ranges = np.linspace(1.0, 30.0, n * beams, dtype=np.float32).reshape(n, beams)
    ranges[0, 0] = np.inf
    ranges[0, 1] = np.nan
    ranges[-1, -1] = 0.01  # below range_min: no return either
    return {
        **header(SEC * 10**9 + np.arange(n) * 13_333_333, "laser_front_2"),
        "angle_min": -fov_rad / 2,
        "angle_max": fov_rad / 2,
        "angle_increment": fov_rad / (beams - 1),
        "time_increment": 1.0 / 75 / beams,
        "scan_time": 1.0 / 75,
        "range_min": 0.1,
        "range_max": 80.0,
        "ranges": ranges,
    }


@pytest.mark.parametrize(("beams", "fov_deg"), [(181, 180.0), (361, 270.0), (2, 1.0)])
def test_laser_scan_any_beam_count_and_fov(beams: int, fov_deg: float) -> None:
    fov = math.radians(fov_deg)
    cols = _scan_cols(4, beams, fov)
    rows = convert("lasers", "sensor_msgs/msg/LaserScan", cols, topic="/laser/front_2")
    assert col(rows, "laser") == ["/laser/front_2"] * 4
    assert col(rows, "frame_id") == ["laser_front_2"] * 4
    np.testing.assert_allclose(col(rows, "angle_min"), -fov / 2, rtol=1e-6)
    np.testing.assert_allclose(col(rows, "angle_increment"), fov / (beams - 1), rtol=1e-6)
    assert rows.table.schema.field("ranges").type == pa.list_(pa.float32())
    got = rows.table.column("ranges").to_pylist()
    assert [len(r) for r in got] == [beams] * 4
    assert math.isinf(got[0][0]) and math.isnan(got[0][1])  # no-returns are kept
    np.testing.assert_array_equal(np.asarray(got[2], dtype=np.float32), cols["ranges"][2])
    assert rows.counts["laser_no_return"].tolist() == [2, 0, 0, 1]
    assert rows.finite.all()


def test_laser_scans_of_varying_beam_counts_in_one_batch() -> None:
    ranges = [
        np.full(3, 5.0, np.float32),
        np.array([np.nan, 2.0], np.float32),
        np.ones(5, np.float32),
    ]
    cols = {
        **header(SEC * 10**9 + np.arange(3)),
        "angle_increment": 0.01,
        "range_min": 0.1,
        "range_max": 80.0,
        "ranges": ranges,
    }
    rows = convert("lasers", "sensor_msgs/msg/LaserScan", cols)
    got = rows.table.column("ranges").to_pylist()
    assert [len(r) for r in got] == [3, 2, 5]
    assert rows.counts["laser_no_return"].tolist() == [0, 1, 0]


def test_a_negative_range_is_no_return_whatever_range_min_claims() -> None:
    """A range below zero is no distance a sensor measures: counted apart from the other
    no-returns (``laser_negative_range``), under a negative range_min as under a positive
    one; the scans that claim a negative range_min are counted too. Every range is kept."""
    cols = _scan_cols(3, 5, 1.0)
    cols["ranges"][0] = [-2.0, -0.5, 3.0, np.nan, 0.0]
    cols["ranges"][1] = [-1.0, 2.0, 3.0, 4.0, 90.0]
    cols["range_min"] = [-5.0, 0.1, -1.0]
    rows = convert("lasers", "sensor_msgs/msg/LaserScan", cols)
    assert rows.counts["laser_negative_range"].tolist() == [2, 1, 0]
    assert rows.counts["laser_no_return"].tolist() == [1, 1, 0]  # NaN; 90 > range_max
    assert rows.counts["laser_negative_range_min"].tolist() == [1, 0, 1]
    np.testing.assert_array_equal(np.asarray(col(rows, "ranges")[0], np.float32), cols["ranges"][0])


def test_a_negative_range_counts_in_ragged_batches_too() -> None:
    cols = {
        **header(SEC * 10**9 + np.arange(2)),
        "angle_increment": 0.01,
        "range_min": -1.0,
        "range_max": 80.0,
        "ranges": [np.array([-0.5, 2.0, np.inf], np.float32), np.array([1.0, -3.0], np.float32)],
    }
    rows = convert("lasers", "sensor_msgs/msg/LaserScan", cols)
    assert rows.counts["laser_negative_range"].tolist() == [1, 1]
    assert rows.counts["laser_no_return"].tolist() == [1, 0]


def test_laser_non_finite_angle_rejects_the_scan() -> None:
    cols = {**_scan_cols(2, 5, 1.0), "angle_increment": [0.01, np.nan]}
    rows = convert("lasers", "sensor_msgs/msg/LaserScan", cols)
    assert rows.finite.tolist() == [True, False]


def test_truth_pose_from_odometry() -> None:
    n = 5
    rng = np.random.default_rng(11)
    angles = rng.uniform([-3, -0.3, -0.3], [3, 0.3, 0.3], (n, 3))  # yaw, pitch, roll
    rot = Rotation.from_euler("ZYX", angles)
    v_world = rng.normal(0, 5, (n, 3))
    v_body = rot.apply(v_world, inverse=True)
    omega = rng.normal(0, 0.3, (n, 3))
    quat = rot.as_quat()
    pos = rng.normal(0, 100, (n, 3))
    cols = {
        **header(SEC * 10**9 + np.arange(n) * 10_000_000, "enu"),
        "child_frame_id": "base_link",
        "pose.pose.position.x": pos[:, 0],
        "pose.pose.position.y": pos[:, 1],
        "pose.pose.position.z": pos[:, 2],
        "pose.pose.orientation.x": quat[:, 0],
        "pose.pose.orientation.y": quat[:, 1],
        "pose.pose.orientation.z": quat[:, 2],
        "pose.pose.orientation.w": quat[:, 3],
        "twist.twist.linear.x": v_body[:, 0],
        "twist.twist.linear.y": v_body[:, 1],
        "twist.twist.linear.z": v_body[:, 2],
        "twist.twist.angular.x": omega[:, 0],
        "twist.twist.angular.y": omega[:, 1],
        "twist.twist.angular.z": omega[:, 2],
    }
    rows = convert("truth_pose", "nav_msgs/msg/Odometry", cols)
    t = rows.table
    np.testing.assert_allclose(t["x"].to_numpy(), pos[:, 0])
    np.testing.assert_allclose(t["yaw"].to_numpy(), angles[:, 0], atol=1e-9)
    np.testing.assert_allclose(t["pitch"].to_numpy(), angles[:, 1], atol=1e-9)
    np.testing.assert_allclose(t["roll"].to_numpy(), angles[:, 2], atol=1e-9)
    for i, name in enumerate(("vx", "vy", "vz")):
        np.testing.assert_allclose(t[name].to_numpy(), v_world[:, i], atol=1e-9)
    np.testing.assert_allclose(t["speed"].to_numpy(), np.hypot(v_world[:, 0], v_world[:, 1]))
    rr, pr, yr = euler_rates_zyx(angles[:, 2], angles[:, 1], *omega.T)
    np.testing.assert_allclose(t["roll_rate"].to_numpy(), rr)
    np.testing.assert_allclose(t["pitch_rate"].to_numpy(), pr)
    np.testing.assert_allclose(t["yaw_rate"].to_numpy(), yr)
    assert rows.metadata["frame_id"] == "enu"
    assert rows.finite.all()


def test_truth_features_and_tf_explode_into_rows() -> None:
    msg = {
        "header": {"stamp": {"sec": SEC, "nanosec": 0}, "frame_id": "enu"},
        "features": [
            {"kind": "rock", "s_start_m": 1.0, "s_end_m": 1.5, "height_m": 0.2, "x_m": 3.0},
            {"kind": "pothole", "s_start_m": 9.0, "s_end_m": 10.0, "y_m": -2.0},
        ],
    }
    decoded = decode_batch(
        "terrain_msgs/msg/RoughFeatureArray",
        [encode_message("terrain_msgs/msg/RoughFeatureArray", msg)],
    )
    ctx = ConvertContext("/truth/features", "truth_features", "x", 0)
    conv = ROLE_SPECS["truth_features"].converter_for(
        "/truth/features", "terrain_msgs/RoughFeatureArray"
    )
    rows = conv(decoded, np.array([SEC * 10**9]), ctx)
    assert rows.table.column("kind").to_pylist() == ["rock", "pothole"]
    assert rows.table.column("x_m").to_pylist() == [3.0, 0.0]
    assert rows.message_of_row is not None and rows.message_of_row.tolist() == [0, 0]


def _one_message(type_name: str) -> dict[str, Any]:
    """A message of ``type_name`` with a stamp, a frame and one element in each array of
    messages: every field a converter may read has a value."""
    spec = plan_for(type_name).spec
    msg: dict[str, Any] = {}
    for f in spec.fields:
        if f.name == "header":
            msg["header"] = {"stamp": {"sec": SEC, "nanosec": 5}, "frame_id": "base_link"}
        elif f.nested is not None and f.is_array and f.array_length is None:
            msg[f.name] = [
                {"header": {"stamp": {"sec": SEC}}} if f.nested.fields[0].name == "header" else {}
            ]
    return msg


def _only(cols: dict[str, Any], paths: tuple[str, ...]) -> dict[str, Any]:
    """The columns a converter declares it reads, and no other: inside an array of messages
    (a column of per-message dicts), only the declared paths of its elements."""
    out: dict[str, Any] = {}
    for key, value in cols.items():
        if key in paths:
            out[key] = value
        inner = tuple(p[len(key) + 1 :] for p in paths if p.startswith(f"{key}."))
        if inner and value.dtype == object:
            out[key] = np.array(
                [{k: v for k, v in m.items() if k in inner} for m in value], dtype=object
            )
    return out


@pytest.mark.parametrize(
    ("role", "type_name"),
    [
        (role, type_name)
        for role, spec in ROLE_SPECS.items()
        for type_name in spec.accepted_types
        if type_name not in spec.decoders
    ],
)
def test_each_converter_reads_only_the_fields_it_declares(role: str, type_name: str) -> None:
    """``RoleSpec.reads`` is what decides whether a log's own schema can serve a role
    (docs/ingest.md): a converter handed only those columns gives the same rows."""
    reads = ROLE_SPECS[role].reads.get(type_name, ())
    assert reads, f"role {role} declares no fields it reads of {type_name}"
    decoded = decode_batch(type_name, [encode_message(type_name, _one_message(type_name))])
    log_t = np.array([SEC * 10**9], dtype=np.int64)
    ctx = ConvertContext("/t", role, type_name, 0)
    convert = ROLE_SPECS[role].converter_for("/t", type_name)
    full = convert(decoded, log_t, ctx)
    assert full.table.num_rows >= 1
    only = convert(_only(decoded, reads), log_t, ctx)
    assert only.table.equals(full.table)
    assert only.metadata == full.metadata

"""The converters: one per accepted message type, decoded columns to a role's table rows.

Converters never drop rows: they return every message's row, plus a ``finite`` mask of rows whose
must-be-finite fields are finite (the ingest stage rejects the others as ``non_finite``) and
per-row counts of things worth reporting but not rejecting (laser no-returns, GPS fixes without
a fix). Decisions documented here:

- gps: ``NO_FIX`` messages are kept with their status and NaN position: the pose stage decides
  by ``pose.gps_min_status``; they are counted as ``gps_no_fix``. A message with a fix but a
  non-finite position is rejected (``non_finite``). The covariance diagonal (east, north, up
  variances) is null when ``position_covariance_type`` is ``COVARIANCE_TYPE_UNKNOWN``.
- heading: ``terrain_msgs/GpsHeading`` gives yaw and yaw_std (a non-finite or negative yaw_std
  becomes null); ``geometry_msgs/QuaternionStamped`` gives the Z-Y-X yaw of the quaternion and,
  as it carries no uncertainty, ``pose.heading_noise_rad`` as yaw_std.
- wheels: ``terrain_msgs/WheelSpeeds`` gives ``speed`` as the mean of the two *rear* wheels,
  which is exactly the speed of base_link (the rear-axle centre) in planar motion, whereas the
  steered front wheels run on wider arcs in a turn. A non-finite rear wheel rejects the row; a
  non-finite front wheel becomes null. ``geometry_msgs/TwistStamped`` and ``nav_msgs/Odometry``
  give ``speed = twist.linear.x`` and null per-wheel columns.
- lasers: ``sensor_msgs/LaserScan`` with any beam count and field of view, one row per scan;
  ``laser`` is the topic. NaN/inf ranges and ranges outside ``[range_min, range_max]`` mean no
  return: they are kept and counted (``laser_no_return``). A finite range below zero is no
  return either, whatever ``range_min`` claims (no sensor measures a negative distance): kept
  and counted apart (``laser_negative_range``); a scan whose ``range_min`` is negative is
  counted (``laser_negative_range_min``) and said on the terminal once per topic
  (:func:`laser_notices`). Extra columns: ``range_min``, ``range_max`` (m, as the message
  gives them) and ``frame_id`` (the laser's frame, to find its mount on tf_static).
- truth_pose: ``nav_msgs/Odometry`` (pose in ``header.frame_id``, twist in ``child_frame_id`` as
  ROS specifies) to the pose columns: Z-Y-X Euler angles, velocity rotated into the world frame,
  Euler-angle rates from the body rates by the Z-Y-X kinematics, speed = horizontal norm. The
  frame is kept as is (the simulator's local ENU) and named in the table metadata.
- truth_features: ``terrain_msgs/RoughFeatureArray``, one row per feature (table without a
  contract schema, written as ``truth_features.parquet``).
- tf_static: ``tf2_msgs/TFMessage``, one row per transform (written as ``tf_static.json``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pyarrow as pa

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.geometry.rotations import (
    euler_rates_zyx,
    quaternion_to_euler_zyx,
    rotate_body_to_world,
)
from toolkit.ingestion.accounts import TopicAccount
from toolkit.ingestion.rows import (
    NS_PER_S,
    Columns,
    ConvertContext,
    RoleRows,
    all_finite,
    explode,
    f64,
    list_array,
    nullable,
    ragged_list_array,
    stamp_times,
    strings,
)

#: NavSatStatus.STATUS_NO_FIX
NAVSAT_STATUS_NO_FIX = -1
#: NavSatFix.COVARIANCE_TYPE_UNKNOWN
COVARIANCE_TYPE_UNKNOWN = 0

# The dotted field paths each converter reads. A log whose schema of a type departs from the
# toolkit's layout is decoded by its own schema when every path its role's converter reads is
# there, by name and with its standard type (``RoleSpec.reads``; docs/ingest.md).
# ``tests/ingestion/test_converters.py`` checks each converter needs no other field.

#: The header stamp, which every stamped message's converter reads.
STAMP_READS: tuple[str, ...] = ("header.stamp.sec", "header.stamp.nanosec")
IMU_READS: tuple[str, ...] = (
    *STAMP_READS,
    *(f"linear_acceleration.{a}" for a in "xyz"),
    *(f"angular_velocity.{a}" for a in "xyz"),
    *(f"orientation.{a}" for a in "xyzw"),
    "orientation_covariance",
)
GPS_READS: tuple[str, ...] = (
    *STAMP_READS,
    "latitude",
    "longitude",
    "altitude",
    "status.status",
    "position_covariance_type",
    "position_covariance",
)
GPS_HEADING_READS: tuple[str, ...] = (*STAMP_READS, "yaw", "yaw_std")
QUATERNION_READS: tuple[str, ...] = (*STAMP_READS, *(f"quaternion.{a}" for a in "xyzw"))
WHEEL_SPEEDS_READS: tuple[str, ...] = (
    *STAMP_READS,
    "front_left",
    "front_right",
    "rear_left",
    "rear_right",
)
TWIST_READS: tuple[str, ...] = (*STAMP_READS, "twist.linear.x")
ODOMETRY_SPEED_READS: tuple[str, ...] = (*STAMP_READS, "twist.twist.linear.x")
SCAN_READS: tuple[str, ...] = (
    *STAMP_READS,
    "header.frame_id",
    "angle_min",
    "angle_increment",
    "time_increment",
    "range_min",
    "range_max",
    "ranges",
)
ODOMETRY_POSE_READS: tuple[str, ...] = (
    *STAMP_READS,
    "header.frame_id",
    "child_frame_id",
    *(f"pose.pose.position.{a}" for a in "xyz"),
    *(f"pose.pose.orientation.{a}" for a in "xyzw"),
    *(f"twist.twist.linear.{a}" for a in "xyz"),
    *(f"twist.twist.angular.{a}" for a in "xyz"),
)


def imu_from_imu(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/Imu -> t_ns, accel_* (m/s^2, IMU frame), gyro_* (rad/s), and the
    orientation the IMU reports, if it reports one.

    REP 145: ``orientation_covariance[0] == -1`` means the IMU gives no orientation (its
    quaternion is then null here, and so is a non-finite or zero-length one); an all-zero
    covariance means "unknown" (null covariance, orientation kept).
    """
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    data = {
        "accel_x": f64(cols, "linear_acceleration.x"),
        "accel_y": f64(cols, "linear_acceleration.y"),
        "accel_z": f64(cols, "linear_acceleration.z"),
        "gyro_x": f64(cols, "angular_velocity.x"),
        "gyro_y": f64(cols, "angular_velocity.y"),
        "gyro_z": f64(cols, "angular_velocity.z"),
    }
    quat = np.stack([f64(cols, f"orientation.{a}") for a in "xyzw"], axis=1)
    cov = np.asarray(cols["orientation_covariance"], dtype=np.float64).reshape(-1, 9)
    norm = np.linalg.norm(quat, axis=1)
    no_orientation = (cov[:, 0] == -1.0) | ~np.isfinite(norm) | (norm < 1e-6)
    quat = quat / np.where(no_orientation, 1.0, norm)[:, None]
    diag = cov[:, [0, 4, 8]]
    unknown_cov = no_orientation | ~np.isfinite(diag).all(axis=1) | (diag == 0.0).all(axis=1)
    orientation = {
        f"orientation_{a}": nullable(quat[:, k], no_orientation) for k, a in enumerate("xyzw")
    }
    table = pa.table(
        {
            "t_ns": t_ns,
            **data,
            **orientation,
            "orientation_covariance": list_array(diag, pa.float64(), null=unknown_cov),
        }
    )
    return RoleRows(table, all_finite(*data.values()), missing)


def gps_from_navsatfix(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/NavSatFix -> t_ns, latitude/longitude (deg), altitude (m), status,
    position_covariance (diagonal, m^2; null when unknown), position_covariance_type."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    lat, lon, alt = f64(cols, "latitude"), f64(cols, "longitude"), f64(cols, "altitude")
    status = np.asarray(cols["status.status"], dtype=np.int8)
    cov_type = np.asarray(cols["position_covariance_type"], dtype=np.uint8)
    cov = np.asarray(cols["position_covariance"], dtype=np.float64).reshape(-1, 9)
    no_fix = status <= NAVSAT_STATUS_NO_FIX
    table = pa.table(
        {
            "t_ns": t_ns,
            "latitude": lat,
            "longitude": lon,
            "altitude": alt,
            "status": status,
            "position_covariance": list_array(
                cov[:, [0, 4, 8]], pa.float64(), null=cov_type == COVARIANCE_TYPE_UNKNOWN
            ),
            "position_covariance_type": cov_type,
        }
    )
    finite = no_fix | all_finite(lat, lon, alt)
    return RoleRows(table, finite, missing, counts={"gps_no_fix": no_fix.astype(np.int64)})


def heading_from_gps_heading(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/GpsHeading -> t_ns, yaw (rad, ENU), yaw_std (rad; null if unusable)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    yaw, std = f64(cols, "yaw"), f64(cols, "yaw_std")
    bad_std = ~np.isfinite(std) | (std < 0)
    table = pa.table({"t_ns": t_ns, "yaw": yaw, "yaw_std": nullable(std, bad_std)})
    return RoleRows(table, all_finite(yaw), missing)


def heading_from_quaternion(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """geometry_msgs/QuaternionStamped -> t_ns, yaw (Z-Y-X, rad), yaw_std null: the message
    carries no uncertainty, so the table says "unknown" and the pose stage applies its
    configured ``pose.heading_noise_rad`` (ingest stays independent of pose tuning)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    _, _, yaw = quaternion_to_euler_zyx(
        f64(cols, "quaternion.x"),
        f64(cols, "quaternion.y"),
        f64(cols, "quaternion.z"),
        f64(cols, "quaternion.w"),
    )
    unknown = np.full(len(yaw), np.nan)
    table = pa.table({"t_ns": t_ns, "yaw": yaw, "yaw_std": nullable(unknown, np.isnan(unknown))})
    return RoleRows(table, all_finite(yaw), missing)


def wheels_from_wheel_speeds(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/WheelSpeeds -> t_ns, speed = mean of the rear wheels (m/s), per wheel."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    fl, fr = f64(cols, "front_left"), f64(cols, "front_right")
    rl, rr = f64(cols, "rear_left"), f64(cols, "rear_right")
    table = pa.table(
        {
            "t_ns": t_ns,
            "speed": 0.5 * (rl + rr),
            "front_left": nullable(fl, ~np.isfinite(fl)),
            "front_right": nullable(fr, ~np.isfinite(fr)),
            "rear_left": rl,
            "rear_right": rr,
        }
    )
    return RoleRows(table, all_finite(rl, rr), missing)


def _wheels_from_speed(t_ns: IntArray, missing: BoolArray, speed: FloatArray) -> RoleRows:
    nulls = pa.nulls(len(speed), type=pa.float64())
    table = pa.table(
        {
            "t_ns": t_ns,
            "speed": speed,
            "front_left": nulls,
            "front_right": nulls,
            "rear_left": nulls,
            "rear_right": nulls,
        }
    )
    return RoleRows(table, all_finite(speed), missing)


def wheels_from_twist(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """geometry_msgs/TwistStamped -> t_ns, speed = twist.linear.x (m/s), per wheel null."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    return _wheels_from_speed(t_ns, missing, f64(cols, "twist.linear.x"))


def wheels_from_odometry(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """nav_msgs/Odometry -> t_ns, speed = twist.twist.linear.x (m/s), per wheel null."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    return _wheels_from_speed(t_ns, missing, f64(cols, "twist.twist.linear.x"))


def laser_from_scan(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/LaserScan -> one row per scan: t_ns, laser (topic), angle_min,
    angle_increment (rad), time_increment (s), ranges (list<float32>, m, no-returns kept),
    range_min, range_max (m), frame_id. Counted per scan: ``laser_no_return``,
    ``laser_negative_range`` (beams) and ``laser_negative_range_min`` (the module docstring)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    n = len(t_ns)
    angle_min = np.asarray(cols["angle_min"], dtype=np.float32)
    angle_inc = np.asarray(cols["angle_increment"], dtype=np.float32)
    time_inc = np.asarray(cols["time_increment"], dtype=np.float32)
    rmin = np.asarray(cols["range_min"], dtype=np.float32)
    rmax = np.asarray(cols["range_max"], dtype=np.float32)
    raw = cols["ranges"]
    if raw.dtype == object:  # beam counts differ within the batch
        ranges = ragged_list_array(raw, pa.float32(), np.float32)
        flat = np.asarray(ranges.values.to_numpy(zero_copy_only=False), dtype=np.float32)
        row_of = np.repeat(np.arange(n), np.diff(np.asarray(ranges.offsets.to_numpy())))
        negative, no_return = _range_screen(flat, rmin[row_of], rmax[row_of])
        counts = {
            "laser_no_return": np.bincount(row_of[no_return], minlength=n).astype(np.int64),
            "laser_negative_range": np.bincount(row_of[negative], minlength=n).astype(np.int64),
        }
    else:
        values = np.asarray(raw, dtype=np.float32).reshape(n, -1)
        ranges = list_array(values, pa.float32())
        negative, no_return = _range_screen(values, rmin[:, None], rmax[:, None])
        counts = {
            "laser_no_return": np.count_nonzero(no_return, axis=1).astype(np.int64),
            "laser_negative_range": np.count_nonzero(negative, axis=1).astype(np.int64),
        }
    counts["laser_negative_range_min"] = (rmin < 0).astype(np.int64)
    table = pa.table(
        {
            "t_ns": t_ns,
            "laser": pa.array([ctx.topic] * n, type=pa.string()),
            "angle_min": angle_min,
            "angle_increment": angle_inc,
            "time_increment": time_inc,
            "ranges": ranges,
            "range_min": rmin,
            "range_max": rmax,
            "frame_id": pa.array(np.asarray(cols["header.frame_id"]), type=pa.string()),
        }
    )
    finite = all_finite(angle_min, angle_inc, time_inc)
    return RoleRows(table, finite, missing, counts=counts)


def _range_screen(
    ranges: np.ndarray, range_min: np.ndarray, range_max: np.ndarray
) -> tuple[BoolArray, BoolArray]:
    """The beams that are no return, in two masks of ``ranges``' shape: finite but negative
    (never a return, whatever ``range_min`` says), and the others: NaN/inf or outside
    ``[range_min, range_max]``."""
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(ranges)
        negative = finite & (ranges < 0)
        outside = (ranges < range_min) | (ranges > range_max)
    return negative, ~finite | (outside & ~negative)


def laser_notices(accounts: Mapping[str, TopicAccount]) -> list[str]:
    """What a user must know of the lasers' scans, a line per topic (the terminal says them;
    the manifest counts them): a negative ``range_min`` claims what no sensor can do."""
    out: list[str] = []
    for topic, account in accounts.items():
        c = account.counts
        if account.role != "lasers" or not c["laser_negative_range_min"]:
            continue
        out.append(
            f"{topic}: {c['laser_negative_range_min']} of {account.written} scans give a "
            "negative range_min (no sensor measures a negative distance): a range below 0 is "
            f"never a return ({c['laser_negative_range']} such beams counted as "
            "laser_negative_range, none projected)"
        )
    return out


def pose_from_odometry(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """nav_msgs/Odometry -> the pose columns (x, y, z in the odometry's frame; Z-Y-X angles;
    world-frame velocity; Euler-angle rates; horizontal speed)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    q = (
        f64(cols, "pose.pose.orientation.x"),
        f64(cols, "pose.pose.orientation.y"),
        f64(cols, "pose.pose.orientation.z"),
        f64(cols, "pose.pose.orientation.w"),
    )
    roll, pitch, yaw = quaternion_to_euler_zyx(*q)
    v_body = (
        f64(cols, "twist.twist.linear.x"),
        f64(cols, "twist.twist.linear.y"),
        f64(cols, "twist.twist.linear.z"),
    )
    vx, vy, vz = rotate_body_to_world(q, v_body)
    roll_rate, pitch_rate, yaw_rate = euler_rates_zyx(
        roll,
        pitch,
        f64(cols, "twist.twist.angular.x"),
        f64(cols, "twist.twist.angular.y"),
        f64(cols, "twist.twist.angular.z"),
    )
    data = {
        "x": f64(cols, "pose.pose.position.x"),
        "y": f64(cols, "pose.pose.position.y"),
        "z": f64(cols, "pose.pose.position.z"),
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
        "vx": vx,
        "vy": vy,
        "vz": vz,
        "roll_rate": roll_rate,
        "pitch_rate": pitch_rate,
        "yaw_rate": yaw_rate,
        "speed": np.hypot(vx, vy),
    }
    table = pa.table({"t_ns": t_ns, **data})
    frames = np.unique(np.asarray(cols["header.frame_id"]))
    meta = {"frame_id": ",".join(str(f) for f in frames.tolist())}
    children = np.unique(np.asarray(cols["child_frame_id"]))
    meta["child_frame_id"] = ",".join(str(f) for f in children.tolist())
    return RoleRows(table, all_finite(*data.values()), missing, metadata=meta)


_FEATURE_FIELDS: dict[str, str] = {
    name: name
    for name in (
        "kind",
        "s_start_m",
        "s_end_m",
        "d_center_m",
        "width_m",
        "height_m",
        "wavelength_m",
        "x_m",
        "y_m",
    )
}


FEATURES_READS: tuple[str, ...] = (
    *STAMP_READS,
    "header.frame_id",
    *(f"features.{path}" for path in _FEATURE_FIELDS.values()),
)


def features_from_array(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/RoughFeatureArray -> one row per feature: t_ns (the message's), kind and
    the feature's geometry (m, in the message's frame)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    data, counts = explode(cols["features"], _FEATURE_FIELDS, {"kind": str})
    table = pa.table(
        {
            "t_ns": np.repeat(t_ns, counts),
            **data,
            "kind": strings(data["kind"]),
        }
    )
    frames = np.unique(np.asarray(cols["header.frame_id"]))
    return RoleRows(
        table,
        np.ones(len(t_ns), dtype=bool),
        missing,
        metadata={"frame_id": ",".join(str(f) for f in frames.tolist())},
        message_of_row=np.repeat(np.arange(len(t_ns), dtype=np.int64), counts),
    )


_TF_FIELDS: dict[str, str] = {
    "parent_frame": "header.frame_id",
    "child_frame": "child_frame_id",
    "sec": "header.stamp.sec",
    "nanosec": "header.stamp.nanosec",
    "tx": "transform.translation.x",
    "ty": "transform.translation.y",
    "tz": "transform.translation.z",
    "qx": "transform.rotation.x",
    "qy": "transform.rotation.y",
    "qz": "transform.rotation.z",
    "qw": "transform.rotation.w",
}


TF_READS: tuple[str, ...] = tuple(f"transforms.{path}" for path in _TF_FIELDS.values())


def tf_from_tfmessage(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """tf2_msgs/TFMessage -> one row per transform: t_ns (its stamp), parent_frame,
    child_frame, translation tx, ty, tz (m) and rotation quaternion qx, qy, qz, qw."""
    dtypes = {"parent_frame": str, "child_frame": str, "sec": np.int64, "nanosec": np.int64}
    data, counts = explode(cols["transforms"], _TF_FIELDS, dtypes)
    sec, nsec = data.pop("sec"), data.pop("nanosec")
    table = pa.table(
        {
            "t_ns": sec * NS_PER_S + nsec,
            **data,
            "parent_frame": strings(data["parent_frame"]),
            "child_frame": strings(data["child_frame"]),
        }
    )
    n = len(log_time_ns)
    return RoleRows(
        table,
        np.ones(n, dtype=bool),
        np.zeros(n, dtype=bool),
        message_of_row=np.repeat(np.arange(n, dtype=np.int64), counts),
    )


__all__ = [
    "COVARIANCE_TYPE_UNKNOWN",
    "FEATURES_READS",
    "GPS_HEADING_READS",
    "GPS_READS",
    "IMU_READS",
    "ODOMETRY_POSE_READS",
    "ODOMETRY_SPEED_READS",
    "QUATERNION_READS",
    "SCAN_READS",
    "STAMP_READS",
    "TF_READS",
    "TWIST_READS",
    "WHEEL_SPEEDS_READS",
    "NAVSAT_STATUS_NO_FIX",
    "features_from_array",
    "gps_from_navsatfix",
    "heading_from_gps_heading",
    "heading_from_quaternion",
    "imu_from_imu",
    "laser_from_scan",
    "laser_notices",
    "pose_from_odometry",
    "tf_from_tfmessage",
    "wheels_from_odometry",
    "wheels_from_twist",
    "wheels_from_wheel_speeds",
]

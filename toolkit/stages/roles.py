"""Topic roles: which message types each role accepts and how a decoded batch becomes table rows.

A role (``[topics]`` of the configuration) names what a topic means to the pipeline: lasers,
imu, gps, heading, wheels, and on simulated logs the truth. Each role accepts a few standard
ROS 2 message types besides the simulator's own, so another vehicle's logs ingest after a
configuration change alone. For each accepted type a *converter* turns the columns of
:func:`~toolkit.mcapio.cdr.decode_batch` (one numpy array per dotted field path, a whole chunk of
one topic at once) into the contract table's columns, vectorised: no Python work per message.

Time: ``t_ns`` is the header stamp (``sec * 1e9 + nanosec``, int64) corrected by the role's
declared clock offset and latency, ``stamp + clock_offset_ns - latency_ns``
(:meth:`~toolkit.config.TimeConfig.correction_ns`). A message whose stamp is zero carries no
stamp; it takes its log time instead, uncorrected, and is counted (``stamp_missing``).

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
  return: they are kept and counted (``laser_no_return``). Extra columns: ``range_min``,
  ``range_max`` (m) and ``frame_id`` (the laser's frame, to find its mount on tf_static).
- truth_pose: ``nav_msgs/Odometry`` (pose in ``header.frame_id``, twist in ``child_frame_id`` as
  ROS specifies) to the pose columns: Z-Y-X Euler angles, velocity rotated into the world frame,
  Euler-angle rates from the body rates by the Z-Y-X kinematics, speed = horizontal norm. The
  frame is kept as is (the simulator's local ENU) and named in the table metadata.
- truth_features: ``terrain_msgs/RoughFeatureArray``, one row per feature (table without a
  contract schema, written as ``truth_features.parquet``).
- tf_static: ``tf2_msgs/TFMessage``, one row per transform (written as ``tf_static.json``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from toolkit.config import TimeConfig
from toolkit.errors import StageError
from toolkit.mcapio.msgdefs import full_type_name

Columns = Mapping[str, Any]
BoolArray = NDArray[np.bool_]
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: NavSatStatus.STATUS_NO_FIX
NAVSAT_STATUS_NO_FIX = -1
#: NavSatFix.COVARIANCE_TYPE_UNKNOWN
COVARIANCE_TYPE_UNKNOWN = 0

_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class ConvertContext:
    """What a converter needs besides the columns: who the topic is and the declared timing."""

    topic: str
    role: str
    type_name: str
    correction_ns: int

    @classmethod
    def for_topic(cls, topic: str, role: str, type_name: str, time: TimeConfig) -> ConvertContext:
        """The context of one topic under the configuration's clocks (``[time]``)."""
        return cls(
            topic=topic,
            role=role,
            type_name=full_type_name(type_name),
            correction_ns=time.correction_ns(role),
        )


@dataclass
class RoleRows:
    """One decoded batch as table rows (one row per message, in message order).

    ``table`` holds ``t_ns`` and the table's columns. ``finite`` marks messages whose
    must-be-finite fields are finite; ``stamp_missing`` messages took their log time;
    ``counts`` are per-message counts of notable values (e.g. ``laser_no_return``), summed
    over the messages kept; ``metadata`` goes to the table's key-value metadata.

    Most roles give one row per message. A role whose message holds a list (tf_static,
    truth_features) gives one row per element; ``message_of_row`` then says which message
    each row came from, and the header-skew check does not apply (static data).
    """

    table: pa.Table
    finite: BoolArray
    stamp_missing: BoolArray
    counts: dict[str, IntArray] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    message_of_row: IntArray | None = None

    @property
    def t_ns(self) -> IntArray:
        """The rows' corrected times as int64 nanoseconds."""
        return np.asarray(self.table.column("t_ns").to_numpy(), dtype=np.int64)

    @property
    def message_count(self) -> int:
        """How many messages the rows came from."""
        return len(self.finite)


Converter = Callable[[Columns, IntArray, ConvertContext], RoleRows]


@dataclass(frozen=True)
class RoleSpec:
    """A role: the table it fills and a converter per accepted message type."""

    role: str
    table: str
    converters: Mapping[str, Converter]

    @property
    def accepted_types(self) -> tuple[str, ...]:
        """Full names of the accepted message types, sorted."""
        return tuple(sorted(self.converters))

    def converter_for(self, topic: str, type_name: str) -> Converter:
        """The converter of ``type_name``; StageError naming topic, type and accepted types."""
        try:
            name = full_type_name(type_name)
        except Exception:  # a schema name that is not a ROS type name at all
            name = type_name
        conv = self.converters.get(name)
        if conv is None:
            raise StageError(
                f"topic {topic} (role {self.role}) has message type {type_name!r}; "
                f"role {self.role} accepts {', '.join(self.accepted_types)}"
            )
        return conv


# --------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------


def _f64(cols: Columns, path: str) -> FloatArray:
    return np.asarray(cols[path], dtype=np.float64)


def stamp_times(
    cols: Columns, log_time_ns: IntArray, ctx: ConvertContext
) -> tuple[IntArray, BoolArray]:
    """Corrected ``t_ns`` from ``header.stamp`` and the mask of messages without a stamp.

    A zero stamp means none was set: such a message takes its log time, uncorrected.
    """
    sec = np.asarray(cols["header.stamp.sec"], dtype=np.int64)
    nsec = np.asarray(cols["header.stamp.nanosec"], dtype=np.int64)
    stamp = sec * _NS_PER_S + nsec
    missing = (sec == 0) & (nsec == 0)
    t_ns = np.where(missing, np.asarray(log_time_ns, dtype=np.int64), stamp + ctx.correction_ns)
    return t_ns.astype(np.int64, copy=False), missing


def _finite(*arrays: np.ndarray) -> BoolArray:
    ok = np.ones(len(arrays[0]), dtype=bool)
    for a in arrays:
        ok &= np.isfinite(a)
    return ok


def _nullable(values: FloatArray, null: BoolArray) -> pa.Array:
    return pa.array(values, type=pa.float64(), mask=null)


def _list_array(
    values_2d: np.ndarray, value_type: pa.DataType, null: BoolArray | None = None
) -> pa.Array:
    """An (n, k) array as a list array of n lists of k values (null rows where ``null``)."""
    n, k = values_2d.shape
    offsets = pa.array(np.arange(n + 1, dtype=np.int32) * np.int32(k), type=pa.int32())
    flat = pa.array(np.ascontiguousarray(values_2d).reshape(-1), type=value_type)
    mask = None if null is None else pa.array(null, type=pa.bool_())
    return pa.ListArray.from_arrays(offsets, flat, mask=mask)


def _ragged_list_array(rows: np.ndarray, value_type: pa.DataType, dtype: Any) -> pa.Array:
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


def quaternion_to_euler_zyx(
    qx: FloatArray, qy: FloatArray, qz: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(roll, pitch, yaw) in rad of unit quaternions (x, y, z, w), Z-Y-X convention.

    The quaternions are normalised first; a zero or non-finite one gives NaN angles.
    """
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(norm > 1e-12, 1.0 / norm, np.nan)
    x, y, z, w = qx * inv, qy * inv, qz * inv, qw * inv
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def rotate_body_to_world(
    q: tuple[FloatArray, FloatArray, FloatArray, FloatArray], v: tuple[FloatArray, ...]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotate body-frame vectors ``v`` (x, y, z) by unit quaternions ``q`` (x, y, z, w)."""
    qx, qy, qz, qw = q
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(norm > 1e-12, 1.0 / norm, np.nan)
    x, y, z, w = qx * inv, qy * inv, qz * inv, qw * inv
    vx, vy, vz = v
    wx = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz
    wy = 2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz
    wz = 2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz
    return wx, wy, wz


def euler_rates_zyx(
    roll: FloatArray, pitch: FloatArray, p: FloatArray, q: FloatArray, r: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Z-Y-X Euler-angle rates (roll, pitch, yaw rates, rad/s) from body rates p, q, r (rad/s).

    roll' = p + tan(pitch) (q sin(roll) + r cos(roll)); pitch' = q cos(roll) - r sin(roll);
    yaw' = (q sin(roll) + r cos(roll)) / cos(pitch). Singular at pitch = +-90 degrees.
    """
    sr, cr = np.sin(roll), np.cos(roll)
    qr = q * sr + r * cr
    return p + np.tan(pitch) * qr, q * cr - r * sr, qr / np.cos(pitch)


# --------------------------------------------------------------------------------------
# Converters
# --------------------------------------------------------------------------------------


def imu_from_imu(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/Imu -> t_ns, accel_* (m/s^2, IMU frame), gyro_* (rad/s), and the
    orientation the IMU reports, if it reports one.

    REP 145: ``orientation_covariance[0] == -1`` means the IMU gives no orientation (its
    quaternion is then null here, and so is a non-finite or zero-length one); an all-zero
    covariance means "unknown" (null covariance, orientation kept).
    """
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    data = {
        "accel_x": _f64(cols, "linear_acceleration.x"),
        "accel_y": _f64(cols, "linear_acceleration.y"),
        "accel_z": _f64(cols, "linear_acceleration.z"),
        "gyro_x": _f64(cols, "angular_velocity.x"),
        "gyro_y": _f64(cols, "angular_velocity.y"),
        "gyro_z": _f64(cols, "angular_velocity.z"),
    }
    quat = np.stack([_f64(cols, f"orientation.{a}") for a in "xyzw"], axis=1)
    cov = np.asarray(cols["orientation_covariance"], dtype=np.float64).reshape(-1, 9)
    norm = np.linalg.norm(quat, axis=1)
    no_orientation = (cov[:, 0] == -1.0) | ~np.isfinite(norm) | (norm < 1e-6)
    quat = quat / np.where(no_orientation, 1.0, norm)[:, None]
    diag = cov[:, [0, 4, 8]]
    unknown_cov = no_orientation | ~np.isfinite(diag).all(axis=1) | (diag == 0.0).all(axis=1)
    orientation = {
        f"orientation_{a}": _nullable(quat[:, k], no_orientation) for k, a in enumerate("xyzw")
    }
    table = pa.table(
        {
            "t_ns": t_ns,
            **data,
            **orientation,
            "orientation_covariance": _list_array(diag, pa.float64(), null=unknown_cov),
        }
    )
    return RoleRows(table, _finite(*data.values()), missing)


def gps_from_navsatfix(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/NavSatFix -> t_ns, latitude/longitude (deg), altitude (m), status,
    position_covariance (diagonal, m^2; null when unknown), position_covariance_type."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    lat, lon, alt = _f64(cols, "latitude"), _f64(cols, "longitude"), _f64(cols, "altitude")
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
            "position_covariance": _list_array(
                cov[:, [0, 4, 8]], pa.float64(), null=cov_type == COVARIANCE_TYPE_UNKNOWN
            ),
            "position_covariance_type": cov_type,
        }
    )
    finite = no_fix | _finite(lat, lon, alt)
    return RoleRows(table, finite, missing, counts={"gps_no_fix": no_fix.astype(np.int64)})


def heading_from_gps_heading(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/GpsHeading -> t_ns, yaw (rad, ENU), yaw_std (rad; null if unusable)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    yaw, std = _f64(cols, "yaw"), _f64(cols, "yaw_std")
    bad_std = ~np.isfinite(std) | (std < 0)
    table = pa.table({"t_ns": t_ns, "yaw": yaw, "yaw_std": _nullable(std, bad_std)})
    return RoleRows(table, _finite(yaw), missing)


def heading_from_quaternion(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """geometry_msgs/QuaternionStamped -> t_ns, yaw (Z-Y-X, rad), yaw_std null: the message
    carries no uncertainty, so the table says "unknown" and the pose stage applies its
    configured ``pose.heading_noise_rad`` (ingest stays independent of pose tuning)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    _, _, yaw = quaternion_to_euler_zyx(
        _f64(cols, "quaternion.x"),
        _f64(cols, "quaternion.y"),
        _f64(cols, "quaternion.z"),
        _f64(cols, "quaternion.w"),
    )
    unknown = np.full(len(yaw), np.nan)
    table = pa.table({"t_ns": t_ns, "yaw": yaw, "yaw_std": _nullable(unknown, np.isnan(unknown))})
    return RoleRows(table, _finite(yaw), missing)


def wheels_from_wheel_speeds(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/WheelSpeeds -> t_ns, speed = mean of the rear wheels (m/s), per wheel."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    fl, fr = _f64(cols, "front_left"), _f64(cols, "front_right")
    rl, rr = _f64(cols, "rear_left"), _f64(cols, "rear_right")
    table = pa.table(
        {
            "t_ns": t_ns,
            "speed": 0.5 * (rl + rr),
            "front_left": _nullable(fl, ~np.isfinite(fl)),
            "front_right": _nullable(fr, ~np.isfinite(fr)),
            "rear_left": rl,
            "rear_right": rr,
        }
    )
    return RoleRows(table, _finite(rl, rr), missing)


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
    return RoleRows(table, _finite(speed), missing)


def wheels_from_twist(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """geometry_msgs/TwistStamped -> t_ns, speed = twist.linear.x (m/s), per wheel null."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    return _wheels_from_speed(t_ns, missing, _f64(cols, "twist.linear.x"))


def wheels_from_odometry(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """nav_msgs/Odometry -> t_ns, speed = twist.twist.linear.x (m/s), per wheel null."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    return _wheels_from_speed(t_ns, missing, _f64(cols, "twist.twist.linear.x"))


def laser_from_scan(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/LaserScan -> one row per scan: t_ns, laser (topic), angle_min,
    angle_increment (rad), time_increment (s), ranges (list<float32>, m, no-returns kept),
    range_min, range_max (m), frame_id."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    n = len(t_ns)
    angle_min = np.asarray(cols["angle_min"], dtype=np.float32)
    angle_inc = np.asarray(cols["angle_increment"], dtype=np.float32)
    time_inc = np.asarray(cols["time_increment"], dtype=np.float32)
    rmin = np.asarray(cols["range_min"], dtype=np.float32)
    rmax = np.asarray(cols["range_max"], dtype=np.float32)
    raw = cols["ranges"]
    if raw.dtype == object:  # beam counts differ within the batch
        ranges = _ragged_list_array(raw, pa.float32(), np.float32)
        flat = np.asarray(ranges.values.to_numpy(zero_copy_only=False), dtype=np.float32)
        row_of = np.repeat(np.arange(n), np.diff(np.asarray(ranges.offsets.to_numpy())))
        lo, hi = rmin[row_of], rmax[row_of]
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(flat) | (flat < lo) | (flat > hi)
        no_return = np.bincount(row_of[bad], minlength=n).astype(np.int64)
    else:
        values = np.asarray(raw, dtype=np.float32).reshape(n, -1)
        ranges = _list_array(values, pa.float32())
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(values) | (values < rmin[:, None]) | (values > rmax[:, None])
        no_return = np.count_nonzero(bad, axis=1).astype(np.int64)
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
    finite = _finite(angle_min, angle_inc, time_inc)
    return RoleRows(table, finite, missing, counts={"laser_no_return": no_return})


def pose_from_odometry(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """nav_msgs/Odometry -> the pose columns (x, y, z in the odometry's frame; Z-Y-X angles;
    world-frame velocity; Euler-angle rates; horizontal speed)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    q = (
        _f64(cols, "pose.pose.orientation.x"),
        _f64(cols, "pose.pose.orientation.y"),
        _f64(cols, "pose.pose.orientation.z"),
        _f64(cols, "pose.pose.orientation.w"),
    )
    roll, pitch, yaw = quaternion_to_euler_zyx(*q)
    v_body = (
        _f64(cols, "twist.twist.linear.x"),
        _f64(cols, "twist.twist.linear.y"),
        _f64(cols, "twist.twist.linear.z"),
    )
    vx, vy, vz = rotate_body_to_world(q, v_body)
    roll_rate, pitch_rate, yaw_rate = euler_rates_zyx(
        roll,
        pitch,
        _f64(cols, "twist.twist.angular.x"),
        _f64(cols, "twist.twist.angular.y"),
        _f64(cols, "twist.twist.angular.z"),
    )
    data = {
        "x": _f64(cols, "pose.pose.position.x"),
        "y": _f64(cols, "pose.pose.position.y"),
        "z": _f64(cols, "pose.pose.position.z"),
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
    return RoleRows(table, _finite(*data.values()), missing, metadata=meta)


def _explode(
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


def _strings(values: np.ndarray) -> pa.Array:
    return pa.array(np.asarray(values, dtype=str), type=pa.string())


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


def features_from_array(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """terrain_msgs/RoughFeatureArray -> one row per feature: t_ns (the message's), kind and
    the feature's geometry (m, in the message's frame)."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    data, counts = _explode(cols["features"], _FEATURE_FIELDS, {"kind": str})
    table = pa.table(
        {
            "t_ns": np.repeat(t_ns, counts),
            **data,
            "kind": _strings(data["kind"]),
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


def tf_from_tfmessage(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """tf2_msgs/TFMessage -> one row per transform: t_ns (its stamp), parent_frame,
    child_frame, translation tx, ty, tz (m) and rotation quaternion qx, qy, qz, qw."""
    dtypes = {"parent_frame": str, "child_frame": str, "sec": np.int64, "nanosec": np.int64}
    data, counts = _explode(cols["transforms"], _TF_FIELDS, dtypes)
    sec, nsec = data.pop("sec"), data.pop("nanosec")
    table = pa.table(
        {
            "t_ns": sec * _NS_PER_S + nsec,
            **data,
            "parent_frame": _strings(data["parent_frame"]),
            "child_frame": _strings(data["child_frame"]),
        }
    )
    n = len(log_time_ns)
    return RoleRows(
        table,
        np.ones(n, dtype=bool),
        np.zeros(n, dtype=bool),
        message_of_row=np.repeat(np.arange(n, dtype=np.int64), counts),
    )


# --------------------------------------------------------------------------------------
# The roles
# --------------------------------------------------------------------------------------

ROLE_SPECS: dict[str, RoleSpec] = {
    "lasers": RoleSpec("lasers", "laser", {"sensor_msgs/msg/LaserScan": laser_from_scan}),
    "imu": RoleSpec("imu", "imu", {"sensor_msgs/msg/Imu": imu_from_imu}),
    "gps": RoleSpec("gps", "gps", {"sensor_msgs/msg/NavSatFix": gps_from_navsatfix}),
    "heading": RoleSpec(
        "heading",
        "heading",
        {
            "terrain_msgs/msg/GpsHeading": heading_from_gps_heading,
            "geometry_msgs/msg/QuaternionStamped": heading_from_quaternion,
        },
    ),
    "wheels": RoleSpec(
        "wheels",
        "wheels",
        {
            "terrain_msgs/msg/WheelSpeeds": wheels_from_wheel_speeds,
            "geometry_msgs/msg/TwistStamped": wheels_from_twist,
            "nav_msgs/msg/Odometry": wheels_from_odometry,
        },
    ),
    "truth_pose": RoleSpec(
        "truth_pose", "truth_pose", {"nav_msgs/msg/Odometry": pose_from_odometry}
    ),
    "truth_features": RoleSpec(
        "truth_features",
        "truth_features",
        {"terrain_msgs/msg/RoughFeatureArray": features_from_array},
    ),
    "tf_static": RoleSpec("tf_static", "tf_static", {"tf2_msgs/msg/TFMessage": tf_from_tfmessage}),
}


def role_spec(role: str) -> RoleSpec:
    """The spec of a role (KeyError for an unknown one)."""
    return ROLE_SPECS[role]


__all__ = [
    "ROLE_SPECS",
    "ConvertContext",
    "Converter",
    "RoleRows",
    "RoleSpec",
    "euler_rates_zyx",
    "quaternion_to_euler_zyx",
    "role_spec",
    "rotate_body_to_world",
    "stamp_times",
]

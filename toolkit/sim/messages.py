"""Writing the simulated log: its topics and frames, the encoding of messages in columns,
and the release of each block's messages in global log-time order (:class:`Outbox`).

The topics, their types and rates are listed in ``docs/simulator.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.mcapio.cdr_encode import Column
from toolkit.mcapio.writer import LogWriter
from toolkit.sim.sensors import Mount, SensorParams
from toolkit.sim.world import World

TOPIC_LASER = "/laser/front_{}"
TOPIC_IMU = "/imu/data"
TOPIC_GPS = "/gps/fix"
TOPIC_HEADING = "/gps/heading"
TOPIC_WHEELS = "/vehicle/wheel_speeds"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_TRUTH_ODOM = "/truth/odom"
TOPIC_TRUTH_FEATURES = "/truth/features"
TOPIC_LIDAR = "/ouster/points"

WORLD_FRAME = "enu"
BASE_FRAME = "base_link"

NAVSAT_STATUS_NO_FIX = -1
NAVSAT_STATUS_GBAS_FIX = 2
NAVSAT_SERVICE_GPS = 1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2


def register_topics(writer: LogWriter, laser_topics: Sequence[str], lidar: bool = False) -> None:
    """Register every topic of the log with its message type; the lasers' last, then the
    lidar's if the log has one (so a log without it has the channels it always had)."""
    topics = {
        TOPIC_IMU: "sensor_msgs/msg/Imu",
        TOPIC_GPS: "sensor_msgs/msg/NavSatFix",
        TOPIC_HEADING: "terrain_msgs/msg/GpsHeading",
        TOPIC_WHEELS: "terrain_msgs/msg/WheelSpeeds",
        TOPIC_TF_STATIC: "tf2_msgs/msg/TFMessage",
        TOPIC_TRUTH_ODOM: "nav_msgs/msg/Odometry",
        TOPIC_TRUTH_FEATURES: "terrain_msgs/msg/RoughFeatureArray",
        **{t: "sensor_msgs/msg/LaserScan" for t in laser_topics},
    }
    if lidar:
        topics[TOPIC_LIDAR] = "sensor_msgs/msg/PointCloud2"
    for topic, type_name in topics.items():
        writer.register(topic, type_name)


def header_columns(stamp_ns: NDArray[np.int64], frame_id: str) -> dict[str, Column]:
    """``std_msgs/Header`` columns from nanosecond stamps."""
    return {
        "header.stamp.sec": (stamp_ns // 1_000_000_000).astype(np.int32),
        "header.stamp.nanosec": (stamp_ns % 1_000_000_000).astype(np.uint32),
        "header.frame_id": frame_id,
    }


def vector_columns(prefix: str, xyz: FloatArray) -> dict[str, Column]:
    """``geometry_msgs/Vector3`` (or ``Point``) columns ``prefix.x`` .. from ``xyz`` (n, 3)."""
    return {f"{prefix}.x": xyz[:, 0], f"{prefix}.y": xyz[:, 1], f"{prefix}.z": xyz[:, 2]}


def quat_columns(prefix: str, quat_xyzw: FloatArray) -> dict[str, Column]:
    """``geometry_msgs/Quaternion`` columns named ``prefix.x`` .. from ``quat_xyzw`` (n, 4)."""
    return {
        f"{prefix}.x": quat_xyzw[:, 0],
        f"{prefix}.y": quat_xyzw[:, 1],
        f"{prefix}.z": quat_xyzw[:, 2],
        f"{prefix}.w": quat_xyzw[:, 3],
    }


@dataclass
class Outbox:
    """Collects a block's encoded messages and releases them in global log-time order.

    A message whose log time (true time plus latency) reaches into the next block is held
    back, so the file's messages are sorted by log time across the whole log.
    """

    writer: LogWriter
    counts: dict[str, int] = field(default_factory=dict)
    _pending: list[tuple[int, int, str, bytes]] = field(default_factory=list)
    _order: dict[str, int] = field(default_factory=dict)

    def add(self, topic: str, log_time_ns: NDArray[np.int64], payloads: list[bytes]) -> None:
        rank = self._order.setdefault(topic, len(self._order))
        self._pending.extend(
            zip(
                log_time_ns.tolist(),
                [rank] * len(payloads),
                [topic] * len(payloads),
                payloads,
                strict=True,
            )
        )
        self.counts[topic] = self.counts.get(topic, 0) + len(payloads)

    def flush(self, before_ns: int | None) -> None:
        self._pending.sort(key=lambda r: (r[0], r[1]))
        cut = len(self._pending)
        if before_ns is not None:
            cut = next((i for i, r in enumerate(self._pending) if r[0] >= before_ns), cut)
        for log_time, _, topic, payload in self._pending[:cut]:
            self.writer.write(topic, log_time, payload)
        del self._pending[:cut]


def static_transforms(
    params: SensorParams, stamp_ns: int, extra: Sequence[Mount] = ()
) -> dict[str, object]:
    """``/tf_static``: ``base_link`` to every sensor frame, as published: the lasers' nominal
    mounts, not their true (miscalibrated) ones, which only ``terrain_sim`` records; then
    ``extra`` (the lidar's nominal mount, when the log has one)."""
    mounts: list[Mount] = [*params.laser.mounts, params.imu.mount, params.gps.mount, *extra]
    transforms = []
    for m in mounts:
        r, p, y = m.rpy_rad
        qx, qy, qz, qw = Rotation.from_euler("ZYX", [y, p, r]).as_quat()
        transforms.append(
            {
                "header": {
                    "stamp": {
                        "sec": stamp_ns // 1_000_000_000,
                        "nanosec": stamp_ns % 1_000_000_000,
                    },
                    "frame_id": BASE_FRAME,
                },
                "child_frame_id": m.frame_id,
                "transform": {
                    "translation": {"x": m.xyz_m[0], "y": m.xyz_m[1], "z": m.xyz_m[2]},
                    "rotation": {"x": qx, "y": qy, "z": qz, "w": qw},
                },
            }
        )
    return {"transforms": transforms}


def feature_message(world: World, stamp_ns: int) -> dict[str, object]:
    feats = []
    for f in world.features:
        sc = 0.5 * (f.s_start_m + f.s_end_m)
        x, y = world.route.to_world(np.array([sc]), np.array([f.d_center_m]))
        feats.append(
            {
                "kind": f.kind,
                "s_start_m": f.s_start_m,
                "s_end_m": f.s_end_m,
                "d_center_m": f.d_center_m,
                "width_m": f.width_m,
                "height_m": f.height_m,
                "wavelength_m": f.wavelength_m,
                "x_m": float(x[0]),
                "y_m": float(y[0]),
            }
        )
    return {
        "header": {
            "stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000},
            "frame_id": WORLD_FRAME,
        },
        "features": feats,
    }

"""Topic roles: which message types each role accepts and the converter of each.

A role (``[topics]`` of the configuration) names what a topic means to the pipeline: lasers,
imu, gps, heading, wheels, and on simulated logs the truth. Each role accepts a few standard
ROS 2 message types besides the simulator's own, so another vehicle's logs ingest after a
configuration change alone. For each accepted type a *converter* turns the columns of
:func:`~toolkit.mcapio.cdr.decode_batch` (one numpy array per dotted field path, a whole chunk of
one topic at once) into the contract table's columns, vectorised: no Python work per message.
The converters are :mod:`toolkit.ingestion.converters`; what they give back,
:class:`~toolkit.ingestion.rows.RoleRows`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from toolkit.errors import StageError
from toolkit.ingestion.converters import (
    features_from_array,
    gps_from_navsatfix,
    heading_from_gps_heading,
    heading_from_quaternion,
    imu_from_imu,
    laser_from_scan,
    pose_from_odometry,
    tf_from_tfmessage,
    wheels_from_odometry,
    wheels_from_twist,
    wheels_from_wheel_speeds,
)
from toolkit.ingestion.rows import Converter
from toolkit.mcapio.msgdefs import full_type_name


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


__all__ = ["ROLE_SPECS", "RoleSpec", "role_spec"]

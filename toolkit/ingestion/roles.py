"""Topic roles: which message types each role accepts and the converter of each.

A role (``[topics]`` of the configuration) names what a topic means to the pipeline: lasers,
lidars, imu, gps, heading, wheels, and on simulated logs the truth. Each is declared once, in
:data:`ROLE_SPECS`; ingest, ``config init`` and ``info`` read it from there. Each role
accepts a few standard ROS 2 message types besides the simulator's own, so another vehicle's
logs ingest after a configuration change alone. For each accepted type a *converter* turns
the columns of :func:`~toolkit.mcapio.cdr.decode_batch` (one numpy array per dotted field
path, a whole chunk of one topic at once) into the contract table's columns, vectorised: no
Python work per message (a point cloud's own decoder views its points in place).
The converters are :mod:`toolkit.ingestion.converters`; what they give back,
:class:`~toolkit.ingestion.rows.RoleRows`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from toolkit.config import MULTI_TOPIC_ROLES, ROLES
from toolkit.errors import StageError
from toolkit.ingestion.converters import (
    FEATURES_READS,
    GPS_HEADING_READS,
    GPS_READS,
    IMU_READS,
    ODOMETRY_POSE_READS,
    ODOMETRY_SPEED_READS,
    QUATERNION_READS,
    SCAN_READS,
    TF_READS,
    TWIST_READS,
    WHEEL_SPEEDS_READS,
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
from toolkit.ingestion.lidar import POINTCLOUD2, decode_clouds, lidar_from_pointcloud2
from toolkit.ingestion.rows import Converter
from toolkit.mcapio.layout_check import ChannelLayout, field_mismatch
from toolkit.mcapio.msgdefs import full_type_name


@dataclass(frozen=True)
class RoleSpec:
    """A role, declared once: the table it fills, a converter per accepted message type, and
    what the readers of roles say of it.

    ``word`` is what the role is to people ("no GPS compass found"); ``written`` says when
    its table is written: ``"always"`` (a sensor table, empty when the role is absent, so the
    stages read one layout), ``"present"`` (only when the log has the role: the 3-D lidar,
    the truth), ``"json"`` (not a table: the static transforms). ``decoders`` gives, for a
    type decoded by its own reader rather than :func:`~toolkit.mcapio.cdr.decode_batch`, the
    decoder of a topic (a PointCloud2's points are viewed in its own bytes).
    """

    role: str
    table: str
    converters: Mapping[str, Converter]
    word: str
    written: str = "always"
    decoders: Mapping[str, Callable[[str], Decoder]] = field(default_factory=dict)
    #: The role takes several topics (a list in ``[topics]``: every laser, every lidar).
    multi: bool = False
    #: Its table is a row per return, hundreds of millions of rows (the lidar's): written as
    #: the point cloud is (:class:`~toolkit.tableio.TableWriter` ``bulk``).
    bulk: bool = False
    #: Per accepted type, the dotted field paths its converter reads (:meth:`schema_problem`).
    reads: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def accepted_types(self) -> tuple[str, ...]:
        """Full names of the accepted message types, sorted."""
        return tuple(sorted(self.converters))

    def converter_for(self, topic: str, type_name: str) -> Converter:
        """The converter of ``type_name``; StageError naming topic, type and accepted types."""
        conv = self.converters.get(_full_name(type_name))
        if conv is None:
            raise StageError(
                f"topic {topic} (role {self.role}) has message type {type_name!r}; "
                f"role {self.role} accepts {', '.join(self.accepted_types)}"
            )
        return conv

    def decoder_for(self, topic: str, type_name: str) -> Decoder | None:
        """The role's own decoder of ``type_name`` for ``topic``, or None (decode_batch)."""
        make = self.decoders.get(_full_name(type_name))
        return None if make is None else make(topic)

    def schema_problem(self, layout: ChannelLayout) -> str | None:
        """Why this role cannot read a topic whose schema is ``layout`` (None: it can).

        A schema that agrees with the standard layout is always read (by the fast decoder).
        One that departs from it is read by the log's own definition, except for a type the
        role reads by its own decoder (a point cloud: standard layout only); the fields its
        converter reads (``reads``, else every field of the standard layout) must be there by
        name, with their standard types, in any order.
        """
        standard, log = layout.standard, layout.log
        if layout.difference is None or standard is None or log is None:
            return None
        name = standard.name
        if name in self.decoders:
            return f"role {self.role} reads {name} by its standard layout only"
        paths = self.reads.get(name) or tuple(f.name for f in standard.fields)
        mismatch = field_mismatch(standard, log, paths)
        if mismatch is None:
            return None
        return f"role {self.role} cannot read it: the schema {mismatch}"


def _full_name(type_name: str) -> str:
    try:
        return full_type_name(type_name)
    except Exception:  # a schema name that is not a ROS type name at all
        return type_name


#: A topic's decoder: payloads -> one array per dotted field path.
Decoder = Callable[[Sequence[bytes]], dict[str, np.ndarray]]

#: Every role, in the order of :data:`toolkit.config.ROLES`: adding a sensor type is a
#: converter module and a line here (README, "Adding a sensor"). Ingest, ``config init`` and
#: ``info`` read the roles from this mapping when they run, not from a copy made at import.
ROLE_SPECS: dict[str, RoleSpec] = {
    spec.role: spec
    for spec in (
        RoleSpec(
            "lasers",
            "laser",
            {"sensor_msgs/msg/LaserScan": laser_from_scan},
            "laser",
            multi=True,
            reads={"sensor_msgs/msg/LaserScan": SCAN_READS},
        ),
        RoleSpec(
            "lidars",
            "lidar",
            {POINTCLOUD2: lidar_from_pointcloud2},
            "3-D lidar",
            written="present",
            decoders={POINTCLOUD2: decode_clouds},
            multi=True,
            bulk=True,
        ),
        RoleSpec(
            "imu",
            "imu",
            {"sensor_msgs/msg/Imu": imu_from_imu},
            "IMU",
            reads={"sensor_msgs/msg/Imu": IMU_READS},
        ),
        RoleSpec(
            "gps",
            "gps",
            {"sensor_msgs/msg/NavSatFix": gps_from_navsatfix},
            "GPS",
            reads={"sensor_msgs/msg/NavSatFix": GPS_READS},
        ),
        RoleSpec(
            "heading",
            "heading",
            {
                "terrain_msgs/msg/GpsHeading": heading_from_gps_heading,
                "geometry_msgs/msg/QuaternionStamped": heading_from_quaternion,
            },
            "GPS compass",
            reads={
                "terrain_msgs/msg/GpsHeading": GPS_HEADING_READS,
                "geometry_msgs/msg/QuaternionStamped": QUATERNION_READS,
            },
        ),
        RoleSpec(
            "wheels",
            "wheels",
            {
                "terrain_msgs/msg/WheelSpeeds": wheels_from_wheel_speeds,
                "geometry_msgs/msg/TwistStamped": wheels_from_twist,
                "nav_msgs/msg/Odometry": wheels_from_odometry,
            },
            "wheel speed",
            reads={
                "terrain_msgs/msg/WheelSpeeds": WHEEL_SPEEDS_READS,
                "geometry_msgs/msg/TwistStamped": TWIST_READS,
                "nav_msgs/msg/Odometry": ODOMETRY_SPEED_READS,
            },
        ),
        RoleSpec(
            "tf_static",
            "tf_static",
            {"tf2_msgs/msg/TFMessage": tf_from_tfmessage},
            "static transform topic",
            written="json",
            reads={"tf2_msgs/msg/TFMessage": TF_READS},
        ),
        RoleSpec(
            "truth_pose",
            "truth_pose",
            {"nav_msgs/msg/Odometry": pose_from_odometry},
            "true pose (simulated logs only)",
            written="present",
            reads={"nav_msgs/msg/Odometry": ODOMETRY_POSE_READS},
        ),
        RoleSpec(
            "truth_features",
            "truth_features",
            {"terrain_msgs/msg/RoughFeatureArray": features_from_array},
            "true terrain features (simulated logs only)",
            written="present",
            reads={"terrain_msgs/msg/RoughFeatureArray": FEATURES_READS},
        ),
    )
}

if tuple(ROLE_SPECS) != ROLES or {r for r, s in ROLE_SPECS.items() if s.multi} != set(
    MULTI_TOPIC_ROLES
):  # the configuration's [topics] and this list name one set
    raise TypeError(f"ROLE_SPECS {tuple(ROLE_SPECS)} do not match toolkit.config.ROLES {ROLES}")


def role_spec(role: str) -> RoleSpec:
    """The spec of a role (KeyError for an unknown one)."""
    return ROLE_SPECS[role]


def roles_accepting(type_name: str, layout: ChannelLayout | None = None) -> tuple[str, ...]:
    """The roles whose spec accepts ``type_name`` (any spelling of a ROS type name), in
    :data:`ROLE_SPECS` order: what a topic of that type can be to the pipeline. With the
    topic's ``layout`` (its schema compared with the standard one), less the roles that
    cannot read it (:meth:`RoleSpec.schema_problem`)."""
    full = _full_name(type_name)
    return tuple(
        r
        for r, s in ROLE_SPECS.items()
        if full in s.converters and (layout is None or s.schema_problem(layout) is None)
    )


def tables_written(when: str) -> dict[str, str]:
    """Role -> table of the roles whose table is written ``when`` (RoleSpec.written)."""
    return {r: s.table for r, s in ROLE_SPECS.items() if s.written == when}


__all__ = [
    "ROLE_SPECS",
    "Decoder",
    "RoleSpec",
    "role_spec",
    "roles_accepting",
    "tables_written",
]

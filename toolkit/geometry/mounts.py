"""Where each sensor sits on the vehicle: its mount, ``base_link_from_sensor``.

A mount maps a point or vector from the sensor's frame into ``base_link`` (x forward, y left,
z up, origin on the ground below the rear-axle centre)::

    p_base = rotation @ p_sensor + translation_m          (rotation: 3x3, translation: (3,))

Mounts come from the log's static transforms (``/tf_static``, kept by ingest as
``tf_static.json``), looked up by the frame names the configuration gives (``[vehicle]
base_frame``, ``imu_frame``, ``gps_frame``) and chained through intermediate frames when the
tree has them (``base_link -> chassis -> imu_link``). A frame the log does not describe takes
the configuration's position and roll, pitch, yaw (``[vehicle] imu_position_m``,
``imu_orientation_rad``, ``gps_antenna_position_m``); every such fallback is a warning the
caller prints, because a wrong lever arm or a wrongly turned IMU silently ruins the pose.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from toolkit.arrays import FloatArray
from toolkit.config import VehicleConfig
from toolkit.errors import StageError
from toolkit.geometry.static_transforms import TransformRecord, usable_transform

#: Where a mount came from.
FROM_TF_STATIC = "tf_static"
FROM_CONFIG = "config"


@dataclass(frozen=True)
class Mount:
    """``base_link_from_sensor``: ``rotation`` (3, 3) and ``translation_m`` (3,)."""

    frame: str
    translation_m: FloatArray
    rotation: FloatArray
    source: str

    @classmethod
    def from_rpy(
        cls, frame: str, position_m: Sequence[float], rpy_rad: Sequence[float], source: str
    ) -> Mount:
        """A mount from a position and roll, pitch, yaw (Z-Y-X, as ROS and the contract)."""
        roll, pitch, yaw = (float(a) for a in rpy_rad)
        rotation = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
        return cls(frame, np.asarray(position_m, dtype=np.float64), rotation, source)

    def rpy_rad(self) -> tuple[float, float, float]:
        """The rotation as roll, pitch, yaw (rad)."""
        yaw, pitch, roll = Rotation.from_matrix(self.rotation).as_euler("ZYX")
        return float(roll), float(pitch), float(yaw)

    @property
    def is_rotated(self) -> bool:
        """Whether the sensor's axes differ from base_link's (beyond 1e-9 rad)."""
        return not np.allclose(self.rotation, np.eye(3), atol=1e-9)


@dataclass(frozen=True)
class StaticTransform:
    """One static transform: ``parent_from_child``."""

    parent: str
    child: str
    translation_m: FloatArray
    rotation: FloatArray

    @classmethod
    def from_record(cls, record: TransformRecord) -> StaticTransform:
        """A usable transform (:func:`~toolkit.geometry.static_transforms.usable_transform`)
        as a rotation matrix and translation."""
        return cls(
            record.parent,
            record.child,
            np.asarray(record.translation_m, dtype=np.float64),
            Rotation.from_quat(record.rotation_xyzw).as_matrix(),
        )


#: What to do about a ``tf_static.json`` ingest would not have written.
_REINGEST = "not what ingest writes: ingest the log again (--overwrite)"


def read_tf_static(path: Path) -> list[StaticTransform]:
    """The transforms of an ingested ``tf_static.json`` ([] when the file is absent).

    Raises StageError naming the file when it exists but is not what ingest writes: every
    transform usable by :mod:`toolkit.geometry.static_transforms`' rule, one per child frame.
    """
    if not path.is_file():
        return []
    try:
        obj: Any = json.loads(path.read_text(encoding="utf-8"))
        out: list[StaticTransform] = []
        for tf in obj["transforms"]:
            read = TransformRecord(
                str(tf["parent_frame"]),
                str(tf["child_frame"]),
                int(tf.get("t_ns", 0)),
                tuple(float(v) for v in tf["translation_m"]),
                tuple(float(v) for v in tf["rotation_xyzw"]),
            )
            usable = usable_transform(read)
            if isinstance(usable, str):
                raise ValueError(f"{read.parent!r} -> {read.child!r}: {usable}; {_REINGEST}")
            if any(t.child == usable.child for t in out):
                raise ValueError(f"child frame {usable.child!r} twice; {_REINGEST}")
            out.append(StaticTransform.from_record(usable))
    except (
        OSError,
        UnicodeDecodeError,
        json.JSONDecodeError,
        KeyError,
        TypeError,
        ValueError,
    ) as exc:
        raise StageError(f"unreadable static transforms: {exc}", path=path) from exc
    return out


def _missing_where(path: Path, transforms: Sequence[StaticTransform]) -> str:
    """Why a frame has no mount from the log, for the warning saying so."""
    if transforms:
        return "not in the log's /tf_static"
    if path.is_file():  # ingest dropped every transform the log had (its warnings said why)
        return "the log's /tf_static has no usable transform"
    return "the log has no /tf_static"


def chain_to_base(
    frame: str, transforms: Sequence[StaticTransform], base_frame: str
) -> tuple[FloatArray, FloatArray] | None:
    """``base_from_frame`` as (rotation, translation) by walking parents up to
    ``base_frame``; None when ``frame`` is not below it in the tree (or the tree loops)."""
    parent_of: Mapping[str, StaticTransform] = {tf.child: tf for tf in transforms}
    rotation, translation = np.eye(3), np.zeros(3)
    seen = {frame}
    current = frame
    while current != base_frame:
        link = parent_of.get(current)
        if link is None or link.parent in seen:
            return None
        # parent_from_current composed onto what we have: p_parent = R p + t.
        translation = link.rotation @ translation + link.translation_m
        rotation = link.rotation @ rotation
        current = link.parent
        seen.add(current)
    return rotation, translation


@dataclass(frozen=True)
class Mounts:
    """The IMU's and the GPS antenna's mounts, and what the caller must say about them."""

    imu: Mount
    gps: Mount
    warnings: tuple[str, ...]


def sensor_mounts(tf_static_path: Path, vehicle: VehicleConfig, *, gps: bool = True) -> Mounts:
    """The IMU and GPS antenna mounts: from the log's static transforms by the configured
    frame names, else from the configuration (with a warning naming the keys used; none for
    the antenna of a vehicle configured without GPS, ``gps=False``, whose mount is unused)."""
    transforms = read_tf_static(tf_static_path)
    warnings: list[str] = []
    where = _missing_where(tf_static_path, transforms)

    def mount(
        frame: str, position: Sequence[float], rpy: Sequence[float], keys: str, used: bool = True
    ) -> Mount:
        found = chain_to_base(frame, transforms, vehicle.base_frame)
        if found is not None:
            rotation, translation = found
            return Mount(frame, translation, rotation, FROM_TF_STATIC)
        if used:
            warnings.append(
                f"mount of {frame!r}: {where} (below {vehicle.base_frame!r}); using the "
                f"configuration's [vehicle] {keys} = {list(position)}"
                + (f", rpy {list(rpy)}" if any(rpy) else "")
            )
        return Mount.from_rpy(frame, position, rpy, FROM_CONFIG)

    imu = mount(
        vehicle.imu_frame,
        vehicle.imu_position_m,
        vehicle.imu_orientation_rad,
        "imu_position_m/imu_orientation_rad",
    )
    antenna = mount(
        vehicle.gps_frame,
        vehicle.gps_antenna_position_m,
        (0.0, 0.0, 0.0),
        "gps_antenna_position_m",
        used=gps,
    )
    return Mounts(imu, antenna, tuple(warnings))


def frame_mounts(
    tf_static_path: Path, base_frame: str, frames: Sequence[str]
) -> tuple[dict[str, Mount], tuple[str, ...]]:
    """Mounts of sensors known only by their frames (the lasers: ``frame_id`` of their scans)
    from the log's static transforms. Returns the mounts found and one warning per frame
    found nowhere (the configuration has no laser positions: such a sensor's data cannot
    be placed on the vehicle, and the caller drops it)."""
    transforms = read_tf_static(tf_static_path)
    where = _missing_where(tf_static_path, transforms)
    found: dict[str, Mount] = {}
    warnings: list[str] = []
    for frame in sorted(set(frames)):
        chained = chain_to_base(frame, transforms, base_frame) if frame else None
        if chained is None:
            warnings.append(
                f"mount of {frame!r}: {where} (below {base_frame!r}); its data is not used"
            )
            continue
        rotation, translation = chained
        found[frame] = Mount(frame, translation, rotation, FROM_TF_STATIC)
    return found, tuple(warnings)


__all__ = [
    "FROM_CONFIG",
    "FROM_TF_STATIC",
    "Mount",
    "Mounts",
    "StaticTransform",
    "chain_to_base",
    "frame_mounts",
    "read_tf_static",
    "sensor_mounts",
]

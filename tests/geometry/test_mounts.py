"""Sensor mounts: from /tf_static by the configured frame names, else from the config."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from toolkit.config import default_config
from toolkit.errors import StageError
from toolkit.geometry.mounts import FROM_CONFIG, FROM_TF_STATIC, Mount, sensor_mounts


def _tf(parent: str, child: str, xyz: list[float], rpy: list[float]) -> dict[str, object]:
    roll, pitch, yaw = rpy
    quat = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
    return {
        "parent_frame": parent,
        "child_frame": child,
        "t_ns": 0,
        "translation_m": xyz,
        "rotation_xyzw": quat.tolist(),
    }


def _write(path: Path, *transforms: dict[str, object]) -> Path:
    path.write_text(json.dumps({"transforms": list(transforms)}))
    return path


def test_mounts_come_from_tf_static_by_frame_name(tmp_path: Path) -> None:
    tf = _write(
        tmp_path / "tf_static.json",
        _tf("base_link", "imu_link", [0.1, 0.2, 0.9], [0.0, 0.0, 0.0]),
        _tf("base_link", "gps_antenna", [0.6, 0.0, 2.1], [0.0, 0.0, 0.0]),
        _tf("base_link", "my_imu_spare", [9.0, 9.0, 9.0], [0.0, 0.0, 0.0]),  # not by substring
    )
    mounts = sensor_mounts(tf, default_config().vehicle)
    assert mounts.warnings == ()
    assert mounts.imu.source == FROM_TF_STATIC and mounts.gps.source == FROM_TF_STATIC
    np.testing.assert_allclose(mounts.imu.translation_m, [0.1, 0.2, 0.9])
    np.testing.assert_allclose(mounts.gps.translation_m, [0.6, 0.0, 2.1])


def test_mount_chained_through_an_intermediate_frame(tmp_path: Path) -> None:
    """base_link -> chassis (1 m forward, yawed 90 deg) -> imu_link (0.5 m along chassis x)."""
    tf = _write(
        tmp_path / "tf_static.json",
        _tf("chassis", "imu_link", [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]),
        _tf("base_link", "chassis", [1.0, 0.0, 0.2], [0.0, 0.0, np.pi / 2]),
        _tf("base_link", "gps_antenna", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
    )
    imu = sensor_mounts(tf, default_config().vehicle).imu
    np.testing.assert_allclose(imu.translation_m, [1.0, 0.5, 0.2], atol=1e-12)
    np.testing.assert_allclose(imu.rpy_rad(), [0.0, 0.0, np.pi / 2], atol=1e-12)


def test_missing_tf_static_falls_back_to_the_config_with_warnings(tmp_path: Path) -> None:
    vehicle = dataclasses.replace(
        default_config().vehicle,
        imu_frame="imu_link",
        imu_position_m=(0.0, -0.3, 0.52),
        imu_orientation_rad=(np.pi / 2, 0.0, -np.pi / 2),
    )
    mounts = sensor_mounts(tmp_path / "absent.json", vehicle)
    assert mounts.imu.source == FROM_CONFIG and mounts.gps.source == FROM_CONFIG
    assert len(mounts.warnings) == 2
    assert "'imu_link'" in mounts.warnings[0] and "no /tf_static" in mounts.warnings[0]
    assert "imu_position_m" in mounts.warnings[0]
    # roll pi/2 then yaw -pi/2 (the Husky's IMU): its z axis is base_link's -x, its x axis -y.
    imu = mounts.imu
    assert imu.is_rotated
    np.testing.assert_allclose(imu.rotation @ [0, 0, 1], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(imu.rotation @ [1, 0, 0], [0, -1, 0], atol=1e-12)


def test_mount_rpy_round_trip() -> None:
    mount = Mount.from_rpy("x", [1, 2, 3], [0.1, -0.2, 0.3], FROM_CONFIG)
    np.testing.assert_allclose(mount.rpy_rad(), [0.1, -0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(mount.rotation @ mount.rotation.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize(
    "text",
    ['{"transforms": [{"parent_frame": "a"}]}', "not json", '{"transforms": 3}'],
)
def test_malformed_tf_static_is_one_stage_error(tmp_path: Path, text: str) -> None:
    path = tmp_path / "tf_static.json"
    path.write_text(text)
    with pytest.raises(StageError, match="tf_static.json: unreadable static transforms"):
        sensor_mounts(path, default_config().vehicle)


@pytest.mark.parametrize(
    ("transforms", "problem"),
    [
        (
            [{**_tf("base_link", "imu_link", [0, 0, 0], [0, 0, 0]), "rotation_xyzw": [0] * 4}],
            "'base_link' -> 'imu_link': zero_rotation",
        ),
        (
            [
                _tf("base_link", "imu_link", [0.1, 0, 0], [0, 0, 0]),
                _tf("chassis", "imu_link", [0.2, 0, 0], [0, 0, 0]),
            ],
            "child frame 'imu_link' twice",
        ),
    ],
)
def test_a_tf_static_json_ingest_would_not_write_is_refused_by_the_same_rule(
    tmp_path: Path, transforms: list[dict[str, object]], problem: str
) -> None:
    """The stages read tf_static.json by the rule ingest writes it by: a transform it drops
    or a child frame given twice (the first silently lost before) is no file of ingest's."""
    path = _write(tmp_path / "tf_static.json", *transforms)
    with pytest.raises(StageError, match="ingest the log again") as err:
        sensor_mounts(path, default_config().vehicle)
    assert problem in str(err.value)


def test_a_tf_static_json_of_dropped_transforms_says_so(tmp_path: Path) -> None:
    """Ingest dropped every transform the log had: the fallback says the log's ones were
    unusable, not that the log had none."""
    path = _write(tmp_path / "tf_static.json")
    mounts = sensor_mounts(path, default_config().vehicle)
    assert "the log's /tf_static has no usable transform" in mounts.warnings[0]

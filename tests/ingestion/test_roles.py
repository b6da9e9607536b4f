"""Roles: which message types each accepts, by ROS 2 or ROS 1 type name."""

from __future__ import annotations

import pytest

from toolkit.errors import StageError
from toolkit.ingestion.roles import ROLE_SPECS


def test_unaccepted_type_names_topic_type_and_accepted() -> None:
    with pytest.raises(StageError) as err:
        ROLE_SPECS["imu"].converter_for("/imu/data", "sensor_msgs/msg/LaserScan")
    text = str(err.value)
    assert "/imu/data" in text and "sensor_msgs/msg/LaserScan" in text
    assert "sensor_msgs/msg/Imu" in text
    with pytest.raises(StageError, match="QuaternionStamped.*GpsHeading"):
        ROLE_SPECS["heading"].converter_for("/h", "std_msgs/msg/Float64")


def test_ros1_style_type_names_are_accepted() -> None:
    assert ROLE_SPECS["gps"].converter_for("/fix", "sensor_msgs/NavSatFix") is not None

"""Roles: which message types each accepts, by ROS 2 or ROS 1 type name, and what `info`
says of them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from toolkit.errors import StageError
from toolkit.ingestion.roles import ROLE_SPECS, roles_accepting


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


def test_roles_accepting_a_type_come_from_the_specs() -> None:
    """What `terrain info` says a topic can be is read from ROLE_SPECS, any spelling."""
    assert roles_accepting("sensor_msgs/PointCloud2") == ("lidars",)
    assert roles_accepting("sensor_msgs/msg/LaserScan") == ("lasers",)
    assert roles_accepting("nav_msgs/msg/Odometry") == ("wheels", "truth_pose")
    assert roles_accepting("std_msgs/msg/String") == ()
    every = {t for spec in ROLE_SPECS.values() for t in spec.accepted_types}
    assert all(roles_accepting(t) for t in every)


def test_info_names_the_roles_a_real_lidar_logs_topics_can_play() -> None:
    """`terrain info` on the derived Ouster log: its cloud a lidar, its IMU an imu."""
    from click.testing import CliRunner

    from toolkit.cli import main

    log = Path(__file__).parents[1] / "data" / "real-lidar" / "ouster-os1-128.mcap"
    result = CliRunner().invoke(main, ["info", str(log)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[[i for i, ln in enumerate(lines) if ln.startswith("topic ")][0]].endswith("can be")
    rows = {ln.split()[0]: ln.split()[-1] for ln in lines if ln.startswith("/")}
    assert rows == {
        "/tf_static": "tf_static",
        "/ouster/points": "lidars",
        "/ouster/imu": "imu",
        "/derived/odom": "wheels",
    }
    doc = json.loads(CliRunner().invoke(main, ["info", str(log), "--json"]).stdout)
    assert {t["topic"]: t["roles"] for t in doc["topics"]}["/ouster/points"] == ["lidars"]

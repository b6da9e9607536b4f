"""toolkit.config.sections: the default configuration and its sections."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from toolkit.config import (
    SECTIONS,
    default_config,
    load_config,
)

from .files import PACKAGED, PIPELINE, REPO


def test_packaged_default_is_identical_to_pipeline_file() -> None:
    assert PACKAGED.read_bytes() == PIPELINE.read_bytes(), (
        "toolkit/default_config.toml must be a copy of pipelines/stanley2005.toml"
    )


def test_packaged_default_is_declared_as_package_data() -> None:
    """An installed (non-editable) toolkit must ship default_config.toml."""
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    package_data = pyproject["tool"]["setuptools"].get("package-data", {})
    patterns = package_data.get("toolkit", [])
    assert any(Path("default_config.toml").match(p) for p in patterns), (
        'pyproject.toml [tool.setuptools.package-data] needs "toolkit" = ["default_config.toml"]'
    )


def test_default_equals_loading_the_pipeline_file() -> None:
    assert load_config(PIPELINE) == default_config()


def test_default_has_the_papers_settings() -> None:
    cfg = default_config()
    assert cfg.name == "stanley2005"
    assert cfg.topics.lasers == tuple(f"/laser/front_{i}" for i in range(1, 6))
    assert cfg.topics.imu == "/imu/data"
    assert cfg.topics.gps == "/gps/fix"
    assert cfg.topics.heading == "/gps/heading"
    assert cfg.topics.wheels == "/vehicle/wheel_speeds"
    assert cfg.topics.tf_static == "/tf_static"
    assert cfg.topics.truth_pose == "/truth/odom"
    assert cfg.topics.truth_features == "/truth/features"
    assert cfg.vehicle.wheelbase_m == 2.855
    assert cfg.vehicle.track_m == 1.65
    assert cfg.pose.output_rate_hz == 100.0
    assert cfg.label.fir_taps == 40
    assert cfg.label.fir_stop_hz == 10.0
    assert cfg.label.event_length_m == 1.4
    assert cfg.label.rough_threshold_g_per_mph == 0.02
    assert cfg.label.gravity_mps2 == 9.80665
    assert cfg.model.wheel_window_radius_m == 0.3
    assert cfg.learn.lambda_fp == 5.0
    assert len(cfg.learn.initial_alpha) == 10
    assert len(cfg.learn.increment_alpha) == 10
    assert cfg.tables.train_fraction == 0.5
    assert cfg.project.keep == "all"
    assert cfg.evaluate.fpr_points == (0.05, 0.1, 0.2)
    assert SECTIONS == (
        "topics",
        "vehicle",
        "time",
        "pose",
        "project",
        "label",
        "model",
        "learn",
        "tables",
        "evaluate",
        "lidar",
        "imu",
        "online",
    )


def test_config_is_frozen() -> None:
    cfg = default_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.label.fir_taps = 41  # type: ignore[misc]


def test_topics_by_role_and_role_of() -> None:
    topics = default_config().topics
    assert topics.by_role()["lasers"] == topics.lasers
    assert topics.role_of("/laser/front_3") == "lasers"
    assert topics.role_of("/gps/heading") == "heading"
    assert topics.role_of("/nowhere") is None

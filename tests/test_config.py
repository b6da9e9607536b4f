"""Tests of toolkit.config: the default, validation errors, merging, hashing, TOML round-trip."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from toolkit.config import (
    SECTIONS,
    PipelineConfig,
    config_hash,
    default_config,
    dump_toml,
    load_config,
    parse_config,
)
from toolkit.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
PIPELINE = REPO / "pipelines" / "stanley2005.toml"
PACKAGED = REPO / "toolkit" / "default_config.toml"


def write(tmp_path: Path, text: str, name: str = "user.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# -- the default ------------------------------------------------------------------------


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


# -- loading user files -----------------------------------------------------------------


def test_partial_file_takes_defaults_for_missing_keys(tmp_path: Path) -> None:
    path = write(tmp_path, "[label]\nevent_length_m = 2.0\n[topics]\nlasers = ['/scan']\n")
    cfg = load_config(path)
    assert cfg.label.event_length_m == 2.0
    assert cfg.label.fir_taps == 40
    assert cfg.topics.lasers == ("/scan",)
    assert cfg.pose == default_config().pose


def test_optional_topic_may_be_empty(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, '[topics]\nwheels = ""\ntruth_pose = ""\n'))
    assert cfg.topics.wheels is None
    assert cfg.topics.truth_pose is None
    assert "wheels" not in cfg.topics.by_role()


def test_integer_accepted_for_float(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, "[vehicle]\nwheelbase_m = 3\n"))
    assert cfg.vehicle.wheelbase_m == 3.0
    assert isinstance(cfg.vehicle.wheelbase_m, float)


def test_time_correction(tmp_path: Path) -> None:
    text = "[time.latency_ns]\nimu = 2000\n[time.clock_offset_ns]\nimu = 500\n"
    cfg = load_config(write(tmp_path, text))
    assert cfg.time.correction_ns("imu") == -1500
    assert cfg.time.correction_ns("gps") == 0
    assert cfg.time.correction_ns("tf_static") == 0


@pytest.mark.parametrize(
    ("text", "key", "fragment"),
    [
        ("[topics]\nlazers = ['/a']\n", "topics.lazers", "did you mean 'topics.lasers'"),
        ("[labl]\nfir_taps = 40\n", "labl", "unknown key"),
        ("[time.latency_ns]\nimuu = 1\n", "time.latency_ns.imuu", "unknown key"),
        ("[vehicle]\nwheelbase_m = -1.0\n", "vehicle.wheelbase_m", "greater than 0"),
        ("[vehicle]\nwheelbase_m = 'long'\n", "vehicle.wheelbase_m", "expected a number"),
        ("[vehicle]\nwheelbase_m = inf\n", "vehicle.wheelbase_m", "finite"),
        ("[vehicle]\nimu_position_m = [0.0, 1.0]\n", "vehicle.imu_position_m", "exactly 3"),
        ("[label]\nfir_taps = 40.5\n", "label.fir_taps", "expected an integer"),
        ("[label]\nfir_taps = true\n", "label.fir_taps", "expected an integer"),
        ("[label]\nshock_statistic = 'mean'\n", "label.shock_statistic", "one of"),
        ("[learn]\ninitial_alpha = [1.0]\n", "learn.initial_alpha", "exactly 10"),
        ("[learn]\nincrement_alpha = [1.0,1,1,1,1,1,1,1,1,0]\n", "learn.increment_alpha[9]", ""),
        ("[learn]\ninitial_alpha = 1.0\n", "learn.initial_alpha", "expected a list"),
        ("[tables]\ntrain_fraction = 1.0\n", "tables.train_fraction", "must be in (0, 1)"),
        ("[evaluate]\nfpr_points = [0.2, 0.1]\n", "evaluate.fpr_points", "increasing"),
        ("[evaluate]\nfpr_points = [0.1, 0.1]\n", "evaluate.fpr_points", "unique"),
        ("[evaluate]\nbaseline_closest_laser = '/x'\n", "evaluate.baseline_closest_laser", ""),
        ("[topics]\nlasers = ['']\n", "topics.lasers[0]", "must not be empty"),
        ("[topics]\nlasers = ['/a', '/a']\n", "topics.lasers", "unique"),
        ("[topics]\ngps = '/imu/data'\n", "topics.gps", "also plays"),
        ("topics = 3\n", "topics", "expected a table"),
        ("name = ''\n", "name", "must not be empty"),
    ],
)
def test_bad_values_name_file_key_and_value(
    tmp_path: Path, text: str, key: str, fragment: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key}"), message
    assert fragment in message
    assert info.value.path == path


def test_error_shows_offending_value(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"got -7\.5"):
        load_config(write(tmp_path, "[pose]\noutput_rate_hz = -7.5\n"))


def test_invalid_toml_names_file(tmp_path: Path) -> None:
    path = write(tmp_path, "[label\nfir_taps = 40\n")
    with pytest.raises(ConfigError, match="invalid TOML") as info:
        load_config(path)
    assert info.value.path == path


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.toml")


def test_non_utf8_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"name = '\xe9'\n")
    with pytest.raises(ConfigError, match="UTF-8"):
        load_config(path)


# -- hashing ----------------------------------------------------------------------------


def test_hash_is_sha256_hex_and_deterministic() -> None:
    h = config_hash(default_config())
    assert len(h) == 64 and int(h, 16) >= 0
    assert config_hash(default_config()) == h


def test_hash_is_stable_across_processes() -> None:
    code = "from toolkit.config import *; print(config_hash(default_config()))"
    env_hashes = {
        subprocess.run(
            [sys.executable, "-c", code],
            check=True,
            capture_output=True,
            text=True,
            env={"PYTHONHASHSEED": seed},
        ).stdout.strip()
        for seed in ("1", "2")
    }
    assert env_hashes == {config_hash(default_config())}


def test_hash_changes_with_any_value() -> None:
    cfg = default_config()
    changed = dataclasses.replace(cfg, label=dataclasses.replace(cfg.label, event_length_m=1.5))
    assert config_hash(changed) != config_hash(cfg)


def test_section_hash_ignores_other_sections() -> None:
    cfg = default_config()
    changed = dataclasses.replace(cfg, evaluate=dataclasses.replace(cfg.evaluate, lookahead_m=5))
    assert config_hash(changed, ["label", "pose"]) == config_hash(cfg, ["pose", "label"])
    assert config_hash(changed, ["evaluate"]) != config_hash(cfg, ["evaluate"])
    assert config_hash(cfg, ["label"]) != config_hash(cfg)
    with pytest.raises(ValueError):
        config_hash(cfg, ["nope"])


def test_a_hash_of_one_key_ignores_the_rest_of_its_section() -> None:
    """What the tables read of [model] is the tyre window's radius: the patch size does not
    change their hash, the radius does."""
    cfg = default_config()
    keys = ["tables", "model.wheel_window_radius_m"]
    fewer = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, max_points_per_wheel=30))
    wider = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, wheel_window_radius_m=1))
    assert config_hash(fewer, keys) == config_hash(cfg, keys)
    assert config_hash(wider, keys) != config_hash(cfg, keys)
    assert config_hash(cfg, ["model", "model.wheel_window_radius_m"]) == config_hash(cfg, ["model"])
    with pytest.raises(ValueError, match="model.nope"):
        config_hash(cfg, ["model.nope"])


# -- writing ----------------------------------------------------------------------------


def test_dump_round_trips_default() -> None:
    cfg = default_config()
    text = dump_toml(cfg)
    assert tomllib.loads(text)  # valid TOML
    assert parse_config(text) == cfg
    assert config_hash(cfg) in text


def test_dump_round_trips_unusual_values() -> None:
    cfg = default_config()
    odd = dataclasses.replace(
        cfg,
        name='quote " back \\ tab \t nl \n del \x7f é 🚙',
        topics=dataclasses.replace(cfg.topics, wheels=None, truth_features=None),
        vehicle=dataclasses.replace(cfg.vehicle, wheel_radius_m=1e-7, track_m=1e16),
        evaluate=dataclasses.replace(cfg.evaluate, baseline_closest_laser="/laser/front_2"),
    )
    back = parse_config(dump_toml(odd))
    assert back == odd
    assert isinstance(back, PipelineConfig)


def test_dump_is_complete_without_defaults(tmp_path: Path) -> None:
    """A dumped file holds every key: it must not depend on the default to be complete."""
    cfg = default_config()
    raw = tomllib.loads(dump_toml(cfg))
    assert set(raw) == {"name", *SECTIONS}
    assert set(raw["label"]) == {f.name for f in dataclasses.fields(cfg.label)}
    assert set(raw["time"]["latency_ns"]) == {"lasers", "imu", "gps", "heading", "wheels"}


def test_every_role_may_be_absent(tmp_path: Path) -> None:
    """A vehicle without lasers, IMU or GPS is a configuration, not an error: "" (or [])."""
    cfg = load_config(write(tmp_path, "[topics]\nlasers = []\nimu = ''\ngps = ''\nheading = ''\n"))
    assert cfg.topics.lasers == () and cfg.topics.imu is None and cfg.topics.gps is None
    assert set(cfg.topics.absent_roles()) == {"lasers", "imu", "gps", "heading"}
    assert set(cfg.topics.by_role()) == {"wheels", "tf_static", "truth_pose", "truth_features"}


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("[time.latency_ns]\nimu = 18446744073709551616\n", "must fit a signed 64-bit integer"),
        ("[time]\nmax_header_skew_ns = 9223372036854775808\n", "must fit a signed 64-bit"),
        (
            "[time.clock_offset_ns]\ngps = -90000000000000\n",
            "must be in \\[-8.64e\\+13, 8.64e\\+13\\]",
        ),
        ("[pose]\nsigma_alpha = 1e-300\n", "must be in \\[0.001, 1\\]"),
        ("[pose]\ngps_noise_m = nan\n", "finite"),
        ("[pose]\naccel_noise_mps2 = inf\n", "finite"),
    ],
)
def test_ranges_are_validated_before_anything_runs(
    tmp_path: Path, text: str, fragment: str
) -> None:
    """Values that passed validation and then crashed a stage (issue: config accepted, then
    crash) are refused up front, naming file and key."""
    with pytest.raises(ConfigError, match=fragment) as info:
        load_config(write(tmp_path, text))
    assert str(tmp_path) in str(info.value)


def _numeric_fields() -> list[tuple[str, str, Any, Any]]:
    """(section, key, value, rule) of every number or list of numbers in the configuration."""
    from toolkit.config.loading import _fields

    cfg = default_config()
    out = []
    for section in dataclasses.fields(cfg):
        value = getattr(cfg, section.name)
        if not dataclasses.is_dataclass(value):
            continue
        for key, (_, rule) in _fields(type(value)).items():
            v = getattr(value, key)
            items = v if isinstance(v, tuple) else (v,)
            if items and all(isinstance(x, int | float) and not isinstance(x, bool) for x in items):
                out.append((section.name, key, v, rule))
    return out


@pytest.mark.parametrize(
    ("section", "key", "value", "rule"),
    _numeric_fields(),
    ids=[f"{s}.{k}" for s, k, _, _ in _numeric_fields()],
)
def test_every_number_has_a_range_and_a_value_outside_it_is_one_line(
    section: str, key: str, value: Any, rule: Any
) -> None:
    """Absurd but well-typed values (omega 1e9, alpha 1e300, a 1e-6 m event, 100,000 taps)
    fail on reading, in one line naming the key and its valid range."""
    bounds = {k: getattr(rule, k) for k in ("gt", "ge", "lt", "le") if getattr(rule, k) is not None}
    assert bounds, f"{section}.{key} accepts any number"
    if "le" in bounds or "lt" in bounds:
        top = bounds.get("le", bounds.get("lt"))
        bad: float = top * 10 + 10 if top >= 0 else top + 1
    else:
        bad = bounds.get("ge", bounds.get("gt")) - 1
    if isinstance(value, int) or (isinstance(value, tuple) and isinstance(value[0], int)):
        bad = int(bad) + (1 if "le" in bounds or "lt" in bounds else -1)
    new = (bad, *value[1:]) if isinstance(value, tuple) else bad
    cfg = default_config()
    broken = dataclasses.replace(
        cfg, **{section: dataclasses.replace(getattr(cfg, section), **{key: new})}
    )
    with pytest.raises(ConfigError) as err:
        parse_config(dump_toml(broken), source="bad.toml")
    message = str(err.value)
    assert "\n" not in message and f"{section}.{key}" in message and "must be" in message

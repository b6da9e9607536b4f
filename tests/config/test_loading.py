"""toolkit.config.loading: user files over the default, every value checked, errors naming
file, key and value."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

from toolkit.config import (
    default_config,
    dump_toml,
    load_config,
    parse_config,
)
from toolkit.errors import ConfigError

from .files import write


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
        ("[online]\nrefit_every_m = 0.0\n", "online.coordinates_per_update", "only refits"),
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


def test_every_role_may_be_absent(tmp_path: Path) -> None:
    """A vehicle without lasers, IMU or GPS is a configuration, not an error: "" (or [])."""
    cfg = load_config(write(tmp_path, "[topics]\nlasers = []\nimu = ''\ngps = ''\nheading = ''\n"))
    assert cfg.topics.lasers == () and cfg.topics.imu is None and cfg.topics.gps is None
    assert set(cfg.topics.absent_roles()) == {"lasers", "lidars", "imu", "gps", "heading"}
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


def test_the_lidar_pipeline_replaces_the_lasers_with_the_simulators_lidar() -> None:
    cfg = load_config(Path(__file__).resolve().parents[2] / "pipelines" / "lidar.toml")
    assert cfg.topics.lasers == () and cfg.topics.lidars == ("/ouster/points",)
    assert cfg.lidar.time == "ouster" and cfg.project.keep == "near_path"

"""toolkit.config.dump: hashing and the TOML round trip."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from toolkit.config import (
    CONFIG_FORMAT,
    SECTIONS,
    TIMED_ROLES,
    PipelineConfig,
    config_hash,
    default_config,
    dump_toml,
    escape_controls,
    parse_config,
    toml_value,
)


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


@pytest.mark.parametrize(
    "text",
    [
        "\x00\x01\x1f",
        "nl \n cr \r tab \t",
        'q " b \\ \\u0041',
        "\x7f \x85 \x9f",
        "\u2028\u2029",
        "é 🚙 €",
        "",
    ],
)
def test_every_written_string_loads_back_and_holds_no_line_break(text: str) -> None:
    """A TOML string escape for every character a TOML string may not hold raw, and for
    those a reader takes for a line break (C1 controls, U+2028, U+2029) though TOML allows
    them: the value loads back as it was and its line stays one line."""
    line = f"key = {toml_value(text)}"
    assert tomllib.loads(line) == {"key": text}
    assert line.splitlines() == [line]
    comment = f"# {escape_controls(text)}"
    assert tomllib.loads(comment) == {} and comment.splitlines() == [comment]


def test_dump_is_complete_without_defaults(tmp_path: Path) -> None:
    """A dumped file holds every key: it must not depend on the default to be complete."""
    cfg = default_config()
    raw = tomllib.loads(dump_toml(cfg))
    assert set(raw) == {"name", *SECTIONS}
    assert set(raw["label"]) == {f.name for f in dataclasses.fields(cfg.label)}
    assert set(raw["time"]["latency_ns"]) == set(TIMED_ROLES)


def test_settings_new_since_hashing_key_nothing_at_their_default() -> None:
    """The lidar's settings at their defaults leave every hash as before the role existed
    (a laser-only workspace stays up to date); set, they key like any setting."""
    cfg = default_config()
    before = {s: config_hash(cfg, [s]) for s in ("topics", "time", "lidar")}
    lidar_topics = dataclasses.replace(cfg.topics, lidars=("/ouster/points",))
    assert (
        config_hash(dataclasses.replace(cfg, topics=lidar_topics), ["topics"]) != before["topics"]
    )
    ouster = dataclasses.replace(cfg.lidar, time="ouster")
    assert config_hash(dataclasses.replace(cfg, lidar=ouster), ["lidar"]) != before["lidar"]
    # What the hash of [topics] was before lidars existed: the eight roles of a laser vehicle.
    laser_only = {f.name: getattr(cfg.topics, f.name) for f in dataclasses.fields(cfg.topics)}
    del laser_only["lidars"]
    canonical = json.dumps(
        {"config_format": CONFIG_FORMAT, "config": {"topics": json.loads(json.dumps(laser_only))}},
        sort_keys=True,
        separators=(",", ":"),
    )
    assert before["topics"] == hashlib.sha256(canonical.encode("ascii")).hexdigest()

"""toolkit.tableio.schemas: the contract's schemas, types and columns."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest

from toolkit.errors import SchemaError
from toolkit.tableio import (
    TableWriter,
    load_table_schema,
    parse_arrow_type,
    read_table,
    table_schema_names,
    write_table,
)

from .tables import CFG, SHA

# The contract's minimum columns and units, per table (units in the contract's conventions).
POSE: dict[str, str | None] = {
    "t_ns": "ns",
    **dict.fromkeys(["x", "y", "z"], "m"),
    **dict.fromkeys(["roll", "pitch", "yaw"], "rad"),
    **dict.fromkeys(["vx", "vy", "vz", "speed"], "m/s"),
    **dict.fromkeys(["roll_rate", "pitch_rate", "yaw_rate"], "rad/s"),
}
EVENTS: dict[str, str | None] = {
    "event_id": "",
    "t_start_ns": "ns",
    "t_end_ns": "ns",
    "s_start_m": "m",
    "s_end_m": "m",
    "speed_mph": "mph",
    "shock_g": "G",
    "ruggedness": "G/mph",
    "rough": "",
}
CONTRACT: dict[str, dict[str, str | None]] = {
    "imu": {
        "t_ns": "ns",
        **dict.fromkeys(["accel_x", "accel_y", "accel_z"], "m/s^2"),
        **dict.fromkeys(["gyro_x", "gyro_y", "gyro_z"], "rad/s"),
    },
    "gps": {
        "t_ns": "ns",
        "latitude": None,
        "longitude": None,
        "altitude": "m",
        "status": None,
        "position_covariance": None,
    },
    "heading": {"t_ns": "ns", "yaw": "rad", "yaw_std": "rad"},
    "wheels": {
        "t_ns": "ns",
        **dict.fromkeys(["speed", "front_left", "front_right", "rear_left", "rear_right"], "m/s"),
    },
    "laser": {
        "t_ns": "ns",
        "laser": None,
        "angle_min": "rad",
        "angle_increment": "rad",
        "time_increment": "s",
        "ranges": "m",
    },
    "lidar": {  # the contract's "<3-D lidar table>": a row a return, in the sensor's frame
        "t_ns": "ns",
        "scan_t_ns": "ns",
        "lidar": None,
        "ring": None,
        "x": "m",
        "y": "m",
        "z": "m",
        "intensity": None,
    },
    "pose": POSE,
    "truth_pose": POSE,
    "points": {
        "t_ns": "ns",
        "laser": None,
        "beam": None,
        "range": "m",
        **dict.fromkeys(["x", "y", "z"], "m"),
        **dict.fromkeys(["roll_rate", "pitch_rate"], "rad/s"),
    },
    "events": EVENTS,
    "tables_events": {"log_id": None, "event_id": None, "split": None, **EVENTS},
    "event_points": {
        "log_id": None,
        "event_id": None,
        "wheel": None,
        **dict.fromkeys(["x", "y", "z"], "m"),
        "tau": "s",
        **dict.fromkeys(["roll_rate", "pitch_rate"], "rad/s"),
        "laser": None,
    },
    "scores": dict.fromkeys(
        ["log_id", "event_id", "split", "r_left", "r_right", "r_combined", "predicted", "rough"]
    ),
}


#: Tables the project writes beyond the outer contract (``terrain online``'s).
BEYOND_CONTRACT = {"online_scores", "online_steps"}


def test_every_contract_table_has_a_schema() -> None:
    assert set(table_schema_names()) == set(CONTRACT) | BEYOND_CONTRACT


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_schema_has_contract_columns_and_units(name: str) -> None:
    schema = load_table_schema(name)
    assert schema.name == name and schema.version >= 1
    for column, unit in CONTRACT[name].items():
        spec = schema.column(column)
        if unit is not None:
            assert spec.unit == unit, f"{name}.{column}"
        assert spec.description
    arrow = schema.arrow_schema()
    assert arrow.names == list(schema.column_names)
    assert arrow.field("t_ns" if "t_ns" in arrow.names else "event_id").type == pa.int64()
    assert arrow.metadata[b"schema_name"] == name.encode()


def test_specific_types() -> None:
    assert load_table_schema("laser").column("ranges").arrow_type() == pa.list_(pa.float32())
    assert load_table_schema("wheels").column("front_left").nullable
    assert not load_table_schema("wheels").column("speed").nullable
    assert load_table_schema("scores").column("rough").arrow_type() == pa.bool_()
    assert load_table_schema("event_points").column("wheel").values == ("left", "right")


def test_unknown_schema() -> None:
    with pytest.raises(SchemaError, match="no table schema named 'nope'"):
        load_table_schema("nope")


def test_parse_arrow_type() -> None:
    assert parse_arrow_type("list<list<int8>>") == pa.list_(pa.list_(pa.int8()))
    assert parse_arrow_type("dictionary<string>") == pa.dictionary(pa.int32(), pa.string())
    with pytest.raises(ValueError):
        parse_arrow_type("decimal")


def test_a_dictionary_column_takes_codes_or_plain_values(tmp_path: Path) -> None:
    """points' laser is stored as codes into a few names: pieces may come as strings or as
    codes into dictionaries that differ from piece to piece; read back, the values are the
    same, as codes, and a column of numbers is still refused."""
    n = 4

    def piece(laser: pa.Array) -> pa.Table:
        return pa.table(
            {
                "t_ns": pa.array(range(n), pa.int64()),
                "laser": laser,
                "beam": pa.array(range(n), pa.int32()),
                "range": pa.array([1.0] * n, pa.float32()),
                **{c: pa.array([0.5] * n) for c in ("x", "y", "z", "roll_rate", "pitch_rate")},
                "scan_t_ns": pa.array([0] * n, pa.int64()),
                "scan_dt_s": pa.array([0.01] * n),
            }
        )

    codes = pa.DictionaryArray.from_arrays(pa.array([0, 1, 1, 0], pa.int32()), pa.array(["b", "a"]))
    path = tmp_path / "points.parquet"
    with TableWriter(path, "points", source_sha256=SHA, config_hash=CFG) as writer:
        writer.write(piece(codes))
        writer.write(piece(pa.array(["a", "c", "a", "a"])))
    back = read_table(path, "points")
    assert pa.types.is_dictionary(back.schema.field("laser").type)
    assert back.column("laser").cast(pa.string()).to_pylist() == list("baabacaa")
    with pytest.raises(SchemaError, match="column 'laser': has type int64"):
        write_table(
            tmp_path / "bad.parquet",
            piece(pa.array(range(n), pa.int64())),
            "points",
            source_sha256=SHA,
            config_hash=CFG,
        )

"""Tests of toolkit.tableio: the contract's schemas, validation, metadata, atomic writes."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import toolkit
import toolkit.tableio as tableio
from toolkit.errors import SchemaError, WorkspaceError
from toolkit.tableio import (
    load_table_schema,
    parse_arrow_type,
    read_table,
    read_table_metadata,
    table_schema_names,
    write_table,
)

SHA = "ab" * 32
CFG = "cd" * 32

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


def test_every_contract_table_has_a_schema() -> None:
    assert set(table_schema_names()) == set(CONTRACT)


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
    with pytest.raises(ValueError):
        parse_arrow_type("decimal")


# -- writing ------------------------------------------------------------------------------


def heading_table(n: int = 3) -> pa.Table:
    return pa.table(
        {
            "t_ns": pa.array(range(n), pa.int64()),
            "yaw": pa.array([0.1 * i for i in range(n)], pa.float64()),
            "yaw_std": pa.array([None] * n, pa.float64()),
        }
    )


def test_write_and_read_back_with_metadata(tmp_path: Path) -> None:
    path = tmp_path / "logs" / "L" / "heading.parquet"
    write_table(
        path,
        heading_table(),
        "heading",
        source_sha256=SHA,
        config_hash=CFG,
        extra_metadata={"enu_origin": '{"lat": 35.0}'},
    )
    meta = read_table_metadata(path)
    assert meta["schema_name"] == "heading"
    assert meta["schema_version"] == "1"
    assert meta["toolkit_version"] == toolkit.__version__
    assert meta["source_sha256"] == SHA
    assert meta["config_hash"] == CFG
    assert meta["enu_origin"] == '{"lat": 35.0}'
    back = read_table(path, "heading")
    assert back.column("yaw").to_pylist() == pytest.approx([0.0, 0.1, 0.2])
    assert back.schema.field("yaw").metadata[b"unit"] == b"rad"
    assert not back.schema.field("t_ns").nullable
    codecs = {pq.ParquetFile(path).metadata.row_group(0).column(i).compression for i in range(3)}
    assert codecs == {"ZSTD"}
    assert sorted(p.name for p in path.parent.iterdir()) == ["heading.parquet"]


def test_several_sources_are_recorded_sorted(tmp_path: Path) -> None:
    path = tmp_path / "h.parquet"
    write_table(path, heading_table(), "heading", source_sha256=["bb", "aa"], config_hash=CFG)
    assert read_table_metadata(path)["source_sha256"] == "aa,bb"


def test_missing_column_names_file_table_column(tmp_path: Path) -> None:
    path = tmp_path / "heading.parquet"
    with pytest.raises(SchemaError) as info:
        write_table(
            path, heading_table().drop(["yaw"]), "heading", source_sha256=SHA, config_hash=CFG
        )
    message = str(info.value)
    assert str(path) in message and "'heading'" in message and "'yaw'" in message
    assert "missing" in message
    assert not path.exists()


def test_wrong_type_is_rejected(tmp_path: Path) -> None:
    table = heading_table().set_column(1, "yaw", pa.array(["a", "b", "c"]))
    with pytest.raises(SchemaError, match=r"column 'yaw': has type string, expected float64"):
        write_table(tmp_path / "h.parquet", table, "heading", source_sha256=SHA, config_hash=CFG)
    narrow = heading_table().set_column(0, "t_ns", pa.array([0, 1, 2], pa.int32()))
    with pytest.raises(SchemaError, match="'t_ns'"):
        write_table(tmp_path / "h.parquet", narrow, "heading", source_sha256=SHA, config_hash=CFG)
    assert list(tmp_path.iterdir()) == []


def test_nulls_in_non_nullable_column(tmp_path: Path) -> None:
    table = heading_table().set_column(1, "yaw", pa.array([0.0, None, 1.0], pa.float64()))
    with pytest.raises(SchemaError, match="'yaw': has 1 null"):
        write_table(tmp_path / "h.parquet", table, "heading", source_sha256=SHA, config_hash=CFG)


def test_extra_columns_kept_and_variants_cast(tmp_path: Path) -> None:
    table = pa.table(
        {
            "extra_note": pa.array(["x", "y"]),
            "t_ns": pa.array([1, 2], pa.int64()),
            "laser": pa.array(["/laser/front_1", "/laser/front_2"], pa.large_string()),
            "angle_min": pa.array([-1.0, -1.0], pa.float32()),
            "angle_increment": pa.array([0.01, 0.01], pa.float32()),
            "time_increment": pa.array([0.0, 0.0], pa.float32()),
            "ranges": pa.array([[1.0, 2.0], [3.0]], pa.large_list(pa.float32())),
        }
    )
    path = tmp_path / "laser.parquet"
    write_table(path, table, "laser", source_sha256=SHA, config_hash=CFG)
    back = read_table(path, "laser")
    assert back.column_names[-1] == "extra_note"
    assert back.schema.field("laser").type == pa.string()
    assert back.schema.field("ranges").type == pa.list_(pa.float32())
    assert back.column("ranges").to_pylist() == [[1.0, 2.0], [3.0]]


def test_allowed_values(tmp_path: Path) -> None:
    schema = load_table_schema("event_points")
    row = {c.name: pa.array([None], c.arrow_type()) for c in schema.columns}
    good = {
        **row,
        "log_id": pa.array(["L", "L"]),
        "event_id": pa.array([0, 0], pa.int64()),
        "wheel": pa.array(["left", "right"]),
        "laser": pa.array(["/l", "/l"]),
        **{
            k: pa.array([0.0, 1.0], pa.float64())
            for k in ("x", "y", "z", "tau", "roll_rate", "pitch_rate")
        },
    }
    path = tmp_path / "event_points.parquet"
    write_table(path, pa.table(good), "event_points", source_sha256=SHA, config_hash=CFG)
    bad = {**good, "wheel": pa.array(["left", "middle"])}
    with pytest.raises(SchemaError, match="'wheel': has value 'middle'"):
        write_table(path, pa.table(bad), "event_points", source_sha256=SHA, config_hash=CFG)


def test_reserved_metadata_keys(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="config_hash"):
        write_table(
            tmp_path / "h.parquet",
            heading_table(),
            "heading",
            source_sha256=SHA,
            config_hash=CFG,
            extra_metadata={"config_hash": "forged"},
        )


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "heading.parquet"
    real = pq.write_table

    def dying_writer(table: pa.Table, where: Path, **kwargs: object) -> None:
        real(table.slice(0, 1), where, **kwargs)  # a partial file...
        raise OSError(28, "No space left on device")  # ...then the disk fills up

    monkeypatch.setattr(tableio.pq, "write_table", dying_writer)
    with pytest.raises(WorkspaceError, match="No space left"):
        write_table(path, heading_table(), "heading", source_sha256=SHA, config_hash=CFG)
    assert list(tmp_path.iterdir()) == []


# -- reading ------------------------------------------------------------------------------


def test_read_table_checks_schema_name_and_version(tmp_path: Path) -> None:
    path = tmp_path / "h.parquet"
    write_table(path, heading_table(), "heading", source_sha256=SHA, config_hash=CFG)
    with pytest.raises(SchemaError, match="holds table 'heading', expected 'imu'"):
        read_table(path, "imu")
    stale = pq.read_table(path)
    stale = stale.replace_schema_metadata({**read_table_metadata(path), "schema_version": "0"})
    pq.write_table(stale, path)
    with pytest.raises(SchemaError, match="schema version 0"):
        read_table(path, "heading")


def test_read_missing_or_garbage(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="no such table"):
        read_table_metadata(tmp_path / "absent.parquet")
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"not parquet at all")
    with pytest.raises(SchemaError, match="not a readable Parquet"):
        read_table_metadata(junk)

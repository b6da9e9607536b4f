"""toolkit.tableio.reader: contract checks on read, checksums, streamed batches."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import toolkit.tableio.reader as tableio_reader
import toolkit.tableio.writer as tableio_writer
from toolkit.errors import SchemaError, WorkspaceError
from toolkit.tableio import (
    TableWriter,
    read_table,
    read_table_metadata,
    write_table,
)

from .tables import CFG, SHA, heading_rows, heading_table


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


def test_rewrite_streams_a_finished_table_into_a_new_one(tmp_path: Path) -> None:
    path = tmp_path / "heading.parquet"
    writer = TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG)
    writer.add_metadata({"frame_id": "old", "kept": "yes"})
    writer.write(heading_rows([1, 2, 3, 4]))
    assert writer.finish()
    moved = writer.rewrite(
        lambda piece, first: piece.filter(pa.array([first + i != 1 for i in range(len(piece))])),
        {"frame_id": "new"},
    )
    assert not any(p.name == ".heading.parquet" for p in tmp_path.iterdir())
    moved.publish()
    assert read_table(path, "heading").column("t_ns").to_pylist() == [1, 3, 4]
    meta = read_table_metadata(path)
    assert meta["frame_id"] == "new" and meta["kept"] == "yes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heading.parquet"]


def test_strings_read_as_dictionaries_come_in_whole_batches(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``as_dictionary`` reads a string column as the dictionary the writer stored; the
    batches (which parquet ends at every row group) are gathered back to ``batch_rows``
    rows, each with one dictionary, and hold exactly the rows a plain read gives."""
    from toolkit.tableio import iter_table_batches

    monkeypatch.setattr(tableio_writer, "ROW_GROUP_ROWS", 10)
    n = 95
    lasers = [f"laser_{k % 3 if k < 50 else 3 + k % 2}" for k in range(n)]  # dictionaries differ
    table = pa.table(
        {
            "log_id": ["a"] * n,
            "event_id": list(range(n)),
            "wheel": ["left", "right"] * (n // 2) + ["left"],
            **{c: [float(k) for k in range(n)] for c in ("x", "y", "z", "tau")},
            **{c: [0.0] * n for c in ("roll_rate", "pitch_rate")},
            "laser": lasers,
            "t_ns": list(range(n)),
        }
    )
    path = tmp_path / "event_points.parquet"
    write_table(path, table, "event_points", source_sha256=SHA, config_hash=CFG)
    assert pq.ParquetFile(path).metadata.num_row_groups == 10
    batches = list(
        iter_table_batches(
            path, "event_points", columns=["t_ns", "laser"], batch_rows=25, as_dictionary=["laser"]
        )
    )
    assert all(b.num_rows >= 25 for b in batches[:-1]) and sum(b.num_rows for b in batches) == n
    assert all(pa.types.is_dictionary(b.schema.field("laser").type) for b in batches)
    got = pa.Table.from_batches(batches)
    assert got.column("laser").cast(pa.string()).to_pylist() == lasers
    assert got.column("t_ns").to_pylist() == list(range(n))
    # Where parquet ends a batch at a row group, the pieces become one batch with one
    # dictionary holding both pieces' values.
    first, second = (
        pa.record_batch({"laser": pa.array(names).dictionary_encode()})
        for names in (["laser_1", "laser_2"], ["laser_3", "laser_1"])
    )
    one = tableio_reader._one_batch([first, second])
    assert one.num_rows == 4 and pa.types.is_dictionary(one.schema.field("laser").type)
    assert one.column("laser").cast(pa.string()).to_pylist() == [
        "laser_1", "laser_2", "laser_3", "laser_1"
    ]  # fmt: skip


def test_row_groups_are_read_alone_by_what_their_statistics_hold(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``row_group_ranges`` gives each row group's min and max of a column; reading
    ``row_groups`` gives exactly their rows, in file order, whatever order they are named."""
    from toolkit.tableio import iter_table_batches, row_group_ranges

    monkeypatch.setattr(tableio_writer, "ROW_GROUP_ROWS", 10)
    n = 35
    table = pa.table(
        {
            "log_id": ["a"] * 20 + ["b"] * 15,
            "event_id": [k // 2 for k in range(n)],
            "wheel": ["left", "right"] * (n // 2) + ["left"],
            **{c: [float(k) for k in range(n)] for c in ("x", "y", "z", "tau")},
            **{c: [0.0] * n for c in ("roll_rate", "pitch_rate")},
            "laser": ["l"] * n,
            "t_ns": list(range(n)),
        }
    )
    path = tmp_path / "event_points.parquet"
    write_table(path, table, "event_points", source_sha256=SHA, config_hash=CFG)
    assert row_group_ranges(path, "event_points", "event_id") == [
        (0, 4),
        (5, 9),
        (10, 14),
        (15, 17),
    ]
    assert row_group_ranges(path, "event_points", "log_id") == [
        ("a", "a"), ("a", "a"), ("b", "b"), ("b", "b")
    ]  # fmt: skip
    got = pa.Table.from_batches(
        iter_table_batches(
            path, "event_points", columns=["t_ns"], batch_rows=100, row_groups=[3, 1]
        )
    )
    assert got.column("t_ns").to_pylist() == list(range(10, 20)) + list(range(30, 35))
    with pytest.raises(SchemaError, match="holds table 'event_points', expected 'imu'"):
        row_group_ranges(path, "imu", "t_ns")

"""toolkit.tableio.writer: validation on write, metadata, atomic and gathered writes."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import toolkit
import toolkit.tableio.writer as tableio_writer
from toolkit.errors import SchemaError, WorkspaceError
from toolkit.tableio import (
    ROW_GROUP_ROWS,
    TableWriter,
    load_table_schema,
    read_table,
    read_table_metadata,
    write_table,
)

from .tables import CFG, SHA, heading_rows, heading_table


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
        "t_ns": pa.array([0, 1], pa.int64()),
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
    """The disk fills up on the second piece: no partial file, and an older table is kept."""
    path = tmp_path / "heading.parquet"
    write_table(path, heading_rows([1, 2]), "heading", source_sha256=SHA, config_hash=CFG)
    before = path.read_bytes()
    real = pq.ParquetWriter.write_table
    calls = {"n": 0}

    def filling_disk(self: pq.ParquetWriter, table: pa.Table, **kwargs: object) -> None:
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(28, "No space left on device")
        real(self, table, **kwargs)

    monkeypatch.setattr(pq.ParquetWriter, "write_table", filling_disk)
    rows = ROW_GROUP_ROWS  # pieces of a whole row group are written as they come
    with (
        pytest.raises(WorkspaceError, match="No space left"),
        TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG) as writer,
    ):
        writer.write(heading_rows(list(range(rows))))
        writer.write(heading_rows(list(range(rows, 2 * rows))))
    assert calls["n"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heading.parquet"]
    assert path.read_bytes() == before


def test_a_failed_write_of_gathered_pieces_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Small pieces are written when the table is finished: the disk filling up then is an
    error there, and no partial file is left beside an older table."""
    path = tmp_path / "heading.parquet"
    write_table(path, heading_rows([1, 2]), "heading", source_sha256=SHA, config_hash=CFG)
    before = path.read_bytes()

    def full_disk(self: pq.ParquetWriter, table: pa.Table, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pq.ParquetWriter, "write_table", full_disk)
    writer = TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG)
    writer.write(heading_rows([5, 6]))  # gathered: nothing written yet
    writer.write(heading_rows([7, 8]))
    with pytest.raises(WorkspaceError, match="No space left"), writer:
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heading.parquet"]
    assert path.read_bytes() == before


def test_gathered_pieces_share_one_dictionary(tmp_path: Path) -> None:
    """Pieces whose dictionary columns carry different dictionaries are written with one
    (a column chunk mixing dictionaries falls back to plain encoding, 4x larger)."""
    path = tmp_path / "points.parquet"
    names = pa.array(["/laser/a", "/laser/b", "/laser/c"])
    schema = load_table_schema("heading")
    pieces = []
    for k in range(4):
        codes = pa.array(np.arange(1_000) % 3, pa.int32())
        order = np.roll(np.arange(3), k)
        laser = pa.DictionaryArray.from_arrays(codes, names.take(pa.array(order)))
        pieces.append(
            heading_rows(list(range(k * 1_000, (k + 1) * 1_000))).append_column("laser", laser)
        )
    with TableWriter(path, schema.name, source_sha256=SHA, config_hash=CFG) as writer:
        for piece in pieces:
            writer.write(piece)

    def laser_bytes(p: Path) -> int:
        f = pq.ParquetFile(p)
        assert f.metadata.num_row_groups == 1
        index = f.schema_arrow.get_field_index("laser")
        return int(f.metadata.row_group(0).column(index).total_compressed_size)

    mixed = tmp_path / "mixed.parquet"  # the pieces as they came, one dictionary each
    pq.write_table(pa.concat_tables(pieces), mixed, compression="zstd")
    assert laser_bytes(path) < laser_bytes(mixed) / 2
    expected = pa.concat_tables(pieces).column("laser").cast(pa.string())
    assert pq.read_table(path).column("laser").cast(pa.string()).equals(expected)


@pytest.mark.parametrize("bulk", [False, True])
def test_small_pieces_are_gathered_into_row_groups(tmp_path: Path, bulk: bool) -> None:
    """Pieces of a few rows are written as whole row groups (each row group costs a reader
    footer memory), the rows as they came; a bulk table's big pieces stay one group each."""
    path = tmp_path / "heading.parquet"
    sizes = [7, 1, 3_000, 20_000, 50_000, 9, 70_000, 2]
    with TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG, bulk=bulk) as writer:
        first = 0
        for n in sizes:
            writer.write(heading_rows(list(range(first, first + n))))
            first += n
    meta = pq.ParquetFile(path).metadata
    assert meta.num_rows == sum(sizes) == writer.rows
    groups = [meta.row_group(i).num_rows for i in range(meta.num_row_groups)]
    # 7 + 1 + 3,000 + 20,000 + 50,000 gathered; 9 + 70,000 one piece; 2 left at the end
    expected = [73_008, 70_009, 2] if bulk else [65_536, 7_472, 65_536, 4_473, 2]
    assert groups == expected
    np.testing.assert_array_equal(
        read_table(path, "heading").column("t_ns").to_numpy(), np.arange(sum(sizes))
    )


def test_interrupted_writer_leaves_nothing(tmp_path: Path) -> None:
    """Any exception inside ``with`` (here Ctrl-C) removes the hidden file."""
    path = tmp_path / "heading.parquet"
    with (
        pytest.raises(KeyboardInterrupt),
        TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG) as writer,
    ):
        writer.write(heading_rows([1, 2, 3]))
        assert len(list(tmp_path.iterdir())) == 1  # written aside, under a hidden name
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_killed_writer_process_never_publishes(tmp_path: Path) -> None:
    """SIGKILL in the middle of a stream: the table's name never holds a partial file."""
    path = tmp_path / "heading.parquet"
    script = (
        "import sys, pyarrow as pa\n"
        "from toolkit.tableio import TableWriter\n"
        f"w = TableWriter({str(path)!r}, 'heading', source_sha256={SHA!r}, config_hash={CFG!r})\n"
        "for i in range(10**6):\n"
        "    w.write(pa.table({'t_ns': [i], 'yaw': [0.0], 'yaw_std': [0.1]}))\n"
        "    if i == 100: print('writing', flush=True)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE)
    try:
        assert child.stdout is not None and child.stdout.readline() == b"writing\n"
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait(timeout=30)
    assert child.returncode == -signal.SIGKILL
    assert not path.exists()
    assert all(p.name.startswith(".heading.parquet.") for p in tmp_path.iterdir())


def test_streamed_pieces_are_one_sorted_checked_table(tmp_path: Path) -> None:
    path = tmp_path / "heading.parquet"
    with TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG, sort_by="t_ns") as writer:
        writer.write(heading_rows([10, 20, 30]))
        writer.add_metadata({"enu_origin": "{}"})
        writer.write(heading_rows([25, 40]))  # one row behind what is written: re-sorted at the end
        writer.add_metadata({"learnt_late": "yes"})
        with pytest.raises(SchemaError, match="column 'yaw'"):
            writer.write(pa.table({"t_ns": [50], "yaw_std": [0.1]}))
    assert writer.rows == 5 and writer.late_rows == 1 and writer.resorted
    table = read_table(path, "heading")
    assert table.column("t_ns").to_pylist() == [10, 20, 25, 30, 40]
    meta = read_table_metadata(path)
    assert meta["enu_origin"] == "{}" and meta["learnt_late"] == "yes"
    assert meta["schema_name"] == "heading" and meta["source_sha256"] == SHA
    assert table.schema.field("yaw").metadata[b"unit"] == b"rad"
    column = pq.ParquetFile(path).metadata.row_group(0).column(0)
    assert column.compression == "ZSTD"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heading.parquet"]


def test_table_without_rows_is_written_empty_with_its_columns(tmp_path: Path) -> None:
    path = tmp_path / "heading.parquet"
    with TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG):
        pass
    table = read_table(path, "heading")
    assert table.num_rows == 0 and table.column_names == ["t_ns", "yaw", "yaw_std"]


def test_flipped_byte_in_a_data_page_is_an_error_not_a_value(tmp_path: Path) -> None:
    path = tmp_path / "heading.parquet"
    yaw = [1.25 + i for i in range(1000)]
    table = pa.table({"t_ns": list(range(1000)), "yaw": yaw, "yaw_std": [0.5] * 1000})
    with TableWriter(path, "heading", source_sha256=SHA, config_hash=CFG) as writer:
        writer.write(table)
    column = pq.ParquetFile(path).metadata.row_group(0).column(1)  # yaw
    data = bytearray(path.read_bytes())
    # A byte in the middle of the yaw column's data page (after its page header).
    at = column.data_page_offset + column.total_compressed_size // 2
    data[at] ^= 0x40
    path.write_bytes(bytes(data))
    with pytest.raises(SchemaError, match="cannot read table 'heading'"):
        read_table(path, "heading")


def test_finish_fsyncs_before_publish_renames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    events: list[str] = []
    real_fsync, real_replace = tableio_writer.fsync_file, tableio_writer.os.replace
    monkeypatch.setattr(
        tableio_writer, "fsync_file", lambda p: (events.append("fsync"), real_fsync(p))
    )
    monkeypatch.setattr(
        tableio_writer.os, "replace", lambda a, b: (events.append("rename"), real_replace(a, b))
    )
    writer = TableWriter(tmp_path / "h.parquet", "heading", source_sha256=SHA, config_hash=CFG)
    writer.write(heading_rows([1]))
    assert writer.finish()
    assert events == ["fsync"] and not (tmp_path / "h.parquet").exists()
    writer.publish()
    assert events == ["fsync", "rename"] and (tmp_path / "h.parquet").exists()
    with pytest.raises(WorkspaceError, match="writer is published"):
        writer.write(heading_rows([2]))

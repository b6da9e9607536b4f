"""TimeWindow: a time-sorted table read forward, holding only what later requests need."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from toolkit.tableio import load_table_schema, write_table
from toolkit.timewindow import Columns, TimeWindow

ROWS = 1_000


def _pose_table(path: Path, t_ns: np.ndarray) -> None:
    """A pose table whose x is the row's index (so rows can be told apart)."""
    schema = load_table_schema("pose")
    cols: dict[str, pa.Array] = {}
    for spec in schema.columns:
        if spec.name == "t_ns":
            cols[spec.name] = pa.array(t_ns, pa.int64())
        elif spec.name == "x":
            cols[spec.name] = pa.array(np.arange(t_ns.size, dtype=np.float64))
        else:
            cols[spec.name] = pa.array(np.zeros(t_ns.size), spec.arrow_type())
    write_table(path, pa.table(cols), "pose", source_sha256="0" * 64, config_hash="test")


@pytest.fixture()
def pose_path(tmp_path: Path) -> Path:
    path = tmp_path / "pose.parquet"
    _pose_table(path, 10_000_000 * np.arange(ROWS, dtype=np.int64))  # 100 Hz from 0
    return path


def test_rows_cover_each_request_across_batches(pose_path: Path) -> None:
    """Each request gets exactly the rows from the last at or before its start to the first
    at or after its end, whatever batches the table is read in, while what lies behind the
    forgotten time is let go."""
    window = TimeWindow(pose_path, "pose", columns=("t_ns", "x"), batch_rows=64)
    rng = np.random.default_rng(0)
    t_lo = 0
    for _ in range(200):
        t_lo += int(rng.integers(0, 60_000_000))
        t_hi = t_lo + int(rng.integers(0, 900_000_000))
        window.forget_before(t_lo - 100_000_000)
        rows = window.rows(t_lo, t_hi)
        first = min(t_lo // 10_000_000, ROWS - 1)
        last = min(-(-t_hi // 10_000_000), ROWS - 1)
        np.testing.assert_array_equal(rows["x"], np.arange(first, last + 1, dtype=np.float64))
        np.testing.assert_array_equal(rows["t_ns"], 10_000_000 * np.arange(first, last + 1))
        held = window.rows(t_lo - 100_000_000, t_lo - 100_000_000)["x"]
        # the oldest row still held is the one at or before the forgotten time
        assert held[0] == max(min((t_lo - 100_000_000) // 10_000_000, ROWS - 1), 0)


def test_requests_past_the_ends_get_the_end_rows(pose_path: Path) -> None:
    window = TimeWindow(pose_path, "pose", columns=("t_ns", "x"), batch_rows=100)
    assert window.rows(-5, -1)["x"].tolist() == [0.0]
    end = 10_000_000 * ROWS
    assert window.rows(end, end + 5)["x"].tolist() == [ROWS - 1.0]


def test_the_transform_sees_every_batch_once_in_order(pose_path: Path) -> None:
    seen: list[float] = []

    def record(cols: Columns) -> Columns:
        seen.extend(cols["x"].tolist())
        return {**cols, "x": cols["x"] * 2.0}

    window = TimeWindow(pose_path, "pose", columns=("t_ns", "x"), batch_rows=77, transform=record)
    rows = window.rows(0, 10_000_000 * ROWS)
    assert seen == list(range(ROWS))
    np.testing.assert_array_equal(rows["x"], 2.0 * np.arange(ROWS))


def test_a_window_needs_the_time_column(pose_path: Path) -> None:
    with pytest.raises(ValueError, match="t_ns"):
        TimeWindow(pose_path, "pose", columns=("x",), batch_rows=10)

"""The replayed events' patches read a window at a time, and the light pass before."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from tests.stages.test_learn import Pipeline
from toolkit.config import default_config
from toolkit.stages.online_patches import NO_POINT, PatchWindows, point_extent
from toolkit.stages.training_data import laser_order, patches_of, split_events
from toolkit.tableio import read_table, row_group_ranges
from toolkit.workspace import Workspace

FIELDS = ("x", "y", "z", "tau", "gamma", "psi", "valid", "count", "laser", "lead")


def test_patches_read_a_window_at_a_time_are_those_read_at_once(pipeline: Pipeline) -> None:
    """Asked for in driven order, out of order, across windows and all at once, small
    windows give every event the patch a whole read gives it, and read anew only when a
    request leaves the window held."""
    cfg = default_config()
    events = split_events(pipeline.ws, None)
    order = laser_order(pipeline.ws, cfg.model)
    whole = patches_of(pipeline.ws, events, cfg.model, order=order)
    extent = point_extent(pipeline.ws, events)
    windows = PatchWindows(pipeline.ws, events, cfg.model, order, extent, window=64)
    assert windows.events == events.num_rows == whole.events
    asks = [np.arange(2 * k, 2 * k + 2) for k in range(0, 100, 7)]  # forward, as the replay
    asks += [np.array([41, 40, 3, 2]), np.arange(2 * events.num_rows)[::-5]]
    for groups in asks:
        got = windows.take(groups)
        assert got.lasers == extent.lasers
        want = whole.take(groups).conform(extent.lasers, whole.n_max)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert windows.reads < len(asks)  # the forward asks mostly fall in the window held


def test_the_light_pass_gives_each_events_last_point_and_the_widest_tyre(
    pipeline: Pipeline,
) -> None:
    """``point_extent``: per event (in the table's order) its latest point's ``t_ns``,
    :data:`NO_POINT` for an event without points; the most points under one tyre; every
    laser."""
    events = split_events(pipeline.ws, None)
    keys = events.select(["log_id", "event_id"])
    ghost = pa.table(
        {
            "log_id": [events.column("log_id")[0].as_py()],
            "event_id": pa.array([10**9], pa.int64()),
        }
    )
    asked = pa.concat_tables([keys, ghost.cast(keys.schema)])
    extent = point_extent(pipeline.ws, asked)
    points = read_table(pipeline.ws.event_points_table, "event_points")
    assert extent.last_seen_ns.size == asked.num_rows and extent.last_seen_ns[-1] == NO_POINT
    for k in (0, events.num_rows // 2, events.num_rows - 1):
        event = int(events.column("event_id")[k].as_py())
        mine = points.filter(pc.equal(points.column("event_id"), event))
        assert extent.last_seen_ns[k] == pc.max(mine.column("t_ns")).as_py()
    per_tyre = points.group_by(["log_id", "event_id", "wheel"]).aggregate([([], "count_all")])
    assert extent.widest == pc.max(per_tyre.column("count_all")).as_py()
    assert extent.lasers == tuple(sorted(set(points.column("laser").to_pylist())))


def test_a_points_table_without_statistics_is_read_whole_and_gives_the_same_patches(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """A points table whose footer gives no statistics (written by another tool) cannot say
    which row groups hold an event, so every window reads every row group: slower, and the
    patches the same."""
    cfg = default_config()
    events = split_events(pipeline.ws, None)
    order = laser_order(pipeline.ws, cfg.model)
    extent = point_extent(pipeline.ws, events)
    with_stats = PatchWindows(pipeline.ws, events, cfg.model, order, extent, window=64)
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(pipeline.ws.root, ws.root)
    table = pq.read_table(ws.event_points_table)
    rows = max(table.num_rows // 7, 1)
    pq.write_table(
        table,
        ws.event_points_table,
        row_group_size=rows,
        write_statistics=False,
        compression="zstd",
    )
    assert all(r is None for r in row_group_ranges(ws.event_points_table, "event_points", "t_ns"))
    without = PatchWindows(ws, events, cfg.model, order, extent, window=64)
    groups = np.arange(2 * min(events.num_rows, 40))
    assert without._row_groups(groups // 2) == list(
        range(pq.ParquetFile(ws.event_points_table).num_row_groups)
    )
    got, want = without.take(groups), with_stats.take(groups)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)

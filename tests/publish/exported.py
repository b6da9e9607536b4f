"""What every test of ``terrain export`` compares the export with: the rows each config and
split must hold, derived from ``tables/events.parquet``, ``tables/event_points.parquet`` and
``report/scores.parquet`` independently of the export's code, and how a client's columns are
compared with them (floats bit for bit). The fixtures are in ``conftest.py``."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import yaml

from toolkit.tableio import load_table_schema, read_table
from toolkit.workspace import Workspace

CONFIGS = ("events", "event_points")
SPLITS = ("train", "test")
POINT_COLUMNS = (
    "log_id",
    "event_id",
    "wheel",
    "x",
    "y",
    "z",
    "tau",
    "roll_rate",
    "pitch_rate",
    "laser",
    "t_ns",
)
ARROW_TYPES = {
    "string": pa.string(),
    "int64": pa.int64(),
    "float64": pa.float64(),
    "bool": pa.bool_(),
}
POLARS_TYPES = {"string": pl.String, "int64": pl.Int64, "float64": pl.Float64, "bool": pl.Boolean}


def event_keys(table: pa.Table) -> list[tuple[str, int]]:
    """(log_id, event_id) of every row."""
    return list(
        zip(table.column("log_id").to_pylist(), table.column("event_id").to_pylist(), strict=True)
    )


def expected_rows(ws: Workspace) -> dict[str, dict[str, pa.Table]]:
    """config -> split -> the rows the export of ``ws`` must hold: the tables' rows of that
    split in the tables' order, the events with the model's ``r_combined`` and ``predicted``
    (joined on log and event), each point in the split of its event."""
    schema = load_table_schema("tables_events")
    events = read_table(ws.events_table, "tables_events", columns=schema.column_names)
    scores = read_table(ws.scores_table, "scores")
    score_row = {key: i for i, key in enumerate(event_keys(scores))}
    take = pa.array([score_row[k] for k in event_keys(events)])
    events = events.append_column(
        "r_combined", scores.column("r_combined").take(take)
    ).append_column("predicted", scores.column("predicted").take(take))
    split_of = dict(zip(event_keys(events), events.column("split").to_pylist(), strict=True))
    points = read_table(ws.event_points_table, "event_points", columns=list(POINT_COLUMNS))
    point_split = np.array([split_of[k] for k in event_keys(points)], dtype=object)
    event_split = np.asarray(events.column("split").to_pylist(), dtype=object)
    return {
        "events": {s: events.filter(pa.array(event_split == s)) for s in SPLITS},
        "event_points": {s: points.filter(pa.array(point_split == s)) for s in SPLITS},
    }


def column_values(values: Any) -> np.ndarray:
    """A column of any client as a numpy array (strings as str objects)."""
    if isinstance(values, pa.ChunkedArray | pa.Array):
        values = values.to_pylist()
    elif isinstance(values, pl.Series):
        values = values.to_list()
    out = [v.decode("utf-8") if isinstance(v, bytes) else v for v in values]
    return np.asarray(out, dtype=object if out and isinstance(out[0], str) else None)


def assert_same_rows(columns: Mapping[str, Any], table: pa.Table, what: str) -> None:
    """``columns`` (name -> values, as a client gave them) are ``table``'s columns, in
    order, with the same values (floats bit for bit, NaN equal to NaN)."""
    assert list(columns) == table.column_names, what
    for name in table.column_names:
        got = column_values(columns[name])
        want = column_values(table.column(name))
        assert got.shape == want.shape, (what, name, got.shape, want.shape)
        if want.dtype.kind == "f":
            assert got.dtype.kind == "f", (what, name, got.dtype)
            assert np.array_equal(got.view(np.int64), want.view(np.int64)), (what, name)
        else:
            assert np.array_equal(got, want), (what, name)


def card_header(out: Path) -> dict[str, Any]:
    """The YAML metadata of the dataset card."""
    text = (out / "README.md").read_text(encoding="utf-8")
    assert text.startswith("---\n")
    header = yaml.safe_load(text.split("---\n", 2)[1])
    assert isinstance(header, dict)
    return header

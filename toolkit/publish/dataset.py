"""What an export is: its configs, splits and files, the columns of each config, and the
facts about the data that the dataset card (:mod:`toolkit.publish.card`) and the Croissant
metadata (:mod:`toolkit.publish.croissant`) both state, so the two cannot disagree.
See ``docs/export.md``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import StageError
from toolkit.model.patches import POINT_COLUMNS as EVENT_POINT_COLUMNS
from toolkit.stages.tables import SplitTotals
from toolkit.tableio import ColumnSpec, load_table_schema

#: The configuration sections the dataset's contents and card depend on: the label's
#: definition, the split, the tyre window and the vehicle (the tyre tracks).
CONFIG_SECTIONS = ("label", "tables", "model", "vehicle")
SPLITS = ("train", "test")
EVENTS = "events"
EVENT_POINTS = "event_points"
#: The columns of a point row, in order (the ``event_points`` schema's, as the model reads them).
POINT_COLUMNS = EVENT_POINT_COLUMNS
#: The model's columns added to the events when ``report/scores.parquet`` scored these tables.
SCORE_COLUMNS = ("r_combined", "predicted")
#: Column type (the schemas' names) -> (``datasets`` dtype, Croissant dataType). The schema
#: names and the ``datasets`` dtypes coincide; Croissant's are schema.org's.
TYPES: dict[str, tuple[str, str]] = {
    "string": ("string", "sc:Text"),
    "int64": ("int64", "sc:Integer"),
    "float64": ("float64", "sc:Float"),
    "bool": ("bool", "sc:Boolean"),
}
CITATION = """@inproceedings{stavens2006selfsupervised,
  title     = {A Self-Supervised Terrain Roughness Estimator for Off-Road Autonomous Driving},
  author    = {Stavens, David and Thrun, Sebastian},
  booktitle = {Proceedings of the 22nd Conference on Uncertainty in Artificial Intelligence (UAI)},
  year      = {2006}
}"""


def data_file(config_name: str, split: str) -> str:
    """The path of one split's Parquet file, relative to the export's root."""
    return f"data/{config_name}/{split}-00000-of-00001.parquet"


def export_config_hash(config: PipelineConfig) -> str:
    """The hash of the configuration sections the export depends on (in every file's
    metadata)."""
    return config_hash(config, sections=CONFIG_SECTIONS)


@dataclass(frozen=True)
class LogSource:
    """One source log of the tables: where it came from and whether it is simulated."""

    log_id: str
    file_name: str
    sha256: str
    size_bytes: int
    #: The simulator's record (``mcap_metadata.json``'s ``terrain_sim``), None for a
    #: recorded log.
    sim: Mapping[str, Any] | None
    #: The manifest's header sections this card quotes (``label``, ``pose``,
    #: ``pose_accuracy``), as recorded.
    header: Mapping[str, Any]


@dataclass(frozen=True)
class Scores:
    """The model's scores of the events (rows aligned with the events table)."""

    r_combined: pa.Array
    predicted: pa.Array
    #: The learned threshold mu (``predicted`` = ``r_combined > mu``), when model.json is
    #: the one that was scored.
    mu: float | None


@dataclass(frozen=True)
class DatasetFacts:
    """Everything the card and the Croissant metadata state, gathered from the data."""

    config: PipelineConfig
    sources: tuple[LogSource, ...]
    #: Each split's events, as written.
    events: Mapping[str, pa.Table]
    #: Each split's point rows.
    points: Mapping[str, int]
    #: Each Parquet file (relative path) -> (bytes, sha256).
    files: Mapping[str, tuple[int, str]]
    #: Each Parquet file (relative path) -> the Arrow size of its rows, bytes (what
    #: ``datasets`` calls a split's ``num_bytes``).
    arrow_bytes: Mapping[str, int]
    #: Each config's columns, in file order.
    columns: Mapping[str, tuple[ColumnSpec, ...]]
    scores: Scores | None
    #: sha256 of the workspace's tables, keyed by layout name (``events_table``...).
    tables: Mapping[str, str]
    #: The tables stage's row counts and rejects, as recorded.
    tables_counts: Mapping[str, int]
    tables_rejects: Mapping[str, int]
    #: When the tables were made (their record's ``finished_utc``, ISO 8601), "" if unknown.
    tables_finished_utc: str = ""

    def counts(self) -> dict[str, SplitTotals]:
        """Events, rough events and point rows per split."""
        return {
            split: SplitTotals(
                self.events[split].num_rows,
                int(
                    np.count_nonzero(
                        self.events[split].column("rough").to_numpy(zero_copy_only=False)
                    )
                ),
                self.points[split],
            )
            for split in SPLITS
        }

    def rows(self, config_name: str, split: str) -> int:
        """Rows of one config's split."""
        return self.events[split].num_rows if config_name == EVENTS else self.points[split]


def dataset_columns(scores: Scores | None) -> dict[str, tuple[ColumnSpec, ...]]:
    """Each config's columns (names, types, units, descriptions), from the table schemas."""
    events = load_table_schema("tables_events").columns
    if scores is not None:
        scored = load_table_schema("scores")
        events = events + tuple(scored.column(name) for name in SCORE_COLUMNS)
    points = load_table_schema("event_points").columns
    if tuple(c.name for c in points) != POINT_COLUMNS:
        raise StageError(f"the event_points schema's columns are not {', '.join(POINT_COLUMNS)}")
    for col in (*events, *points):
        if col.type not in TYPES:
            raise StageError(f"column {col.name!r}: type {col.type} has no dataset dtype")
    return {EVENTS: events, EVENT_POINTS: points}


__all__ = [
    "CITATION",
    "CONFIG_SECTIONS",
    "EVENTS",
    "EVENT_POINTS",
    "POINT_COLUMNS",
    "SCORE_COLUMNS",
    "SPLITS",
    "TYPES",
    "DatasetFacts",
    "LogSource",
    "Scores",
    "data_file",
    "dataset_columns",
    "export_config_hash",
]

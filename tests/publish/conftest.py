"""Fixtures of the export's tests: the workspace is the pipeline run ``test_learn.py`` builds
(label, tables, learn, evaluate on the projected sample, once per session, see
:func:`tests.stages.test_learn.build_pipeline`), exported once per test module."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from tests.publish.exported import POINT_COLUMNS, SPLITS, event_keys
from tests.stages.test_learn import Pipeline
from toolkit.config import PipelineConfig
from toolkit.publish.export import ExportResult, run_export
from toolkit.tableio import load_table_schema, read_table


@pytest.fixture(scope="module")
def config(pipeline: Pipeline) -> PipelineConfig:
    return pipeline.ws.read_config()


@pytest.fixture(scope="module")
def exported(
    pipeline: Pipeline, config: PipelineConfig, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, ExportResult]:
    """The export of the shared pipeline's workspace (into a folder that does not exist)."""
    out = tmp_path_factory.mktemp("export") / "dataset"
    return out, run_export(pipeline.ws, out, config)


@pytest.fixture(scope="module")
def expected(pipeline: Pipeline) -> dict[str, dict[str, pa.Table]]:
    """config -> split -> the rows the export must hold: the tables' rows of that split in
    the tables' order, the events with the model's ``r_combined`` and ``predicted`` (joined
    on log and event), each point in the split of its event."""
    ws = pipeline.ws
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


@pytest.fixture()
def hf_offline(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Path]:
    """``datasets`` kept off the network and out of the home directory; yields its cache."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))
    yield tmp_path / "hf_cache"

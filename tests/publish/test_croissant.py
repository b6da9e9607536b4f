"""The Croissant metadata (``croissant.json``) of ``terrain export``: valid for
``mlcroissant``, and its records are the tables' rows.

``mlcroissant`` builds a record in Python, field by field (about 0.4 ms a point row here):
the sample's ~380 k point rows took it 155 s. So its records of the points config are read
from a narrower export (:func:`narrow`): the same workspace's tables made again with a tyre
window a sixth as wide, ~50 k point rows, every later stage run again. Its ``croissant.json``
must be the shared export's but for what states its data (sizes, checksums, counts), each of
which is checked against its files: the same record sets, fields, types, sources and
transforms, read by ``mlcroissant`` from files of the same columns.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from tests.publish.exported import (
    CONFIGS,
    SPLITS,
    assert_same_rows,
    column_values,
    expected_rows,
)
from tests.stages.test_learn import Pipeline, copy_workspace
from toolkit import __version__
from toolkit.manifest import file_sha256
from toolkit.publish.dataset import data_file
from toolkit.publish.export import ExportResult, run_export
from toolkit.stages.evaluate import SPEC as EVALUATE
from toolkit.stages.learn import SPEC as LEARN
from toolkit.stages.runner import run_stage
from toolkit.stages.tables import SPEC as TABLES

#: The narrower export's tyre window ([model] wheel_window_radius_m; the default is 0.3 m).
NARROW_RADIUS_M = 0.05

Rows = dict[str, dict[str, pa.Table]]


@pytest.fixture(scope="module")
def narrow(pipeline: Pipeline, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Rows]:
    """The export of a copy of the shared workspace whose tables were made again with the
    tyre window of :data:`NARROW_RADIUS_M` (tables, learn and evaluate run again, as a new
    configuration does), and the rows it must hold."""
    root = tmp_path_factory.mktemp("narrow")
    ws = copy_workspace(pipeline.ws, root / "ws")
    cfg = ws.read_config()
    cfg = dataclasses.replace(
        cfg, model=dataclasses.replace(cfg.model, wheel_window_radius_m=NARROW_RADIUS_M)
    )
    ws.write_config(cfg)
    for spec in (TABLES, LEARN, EVALUATE):
        run_stage(spec, ws, cfg, overwrite=True)
    run_export(ws, root / "dataset", cfg)
    return root / "dataset", expected_rows(ws)


def read_croissant(out: Path) -> dict[str, Any]:
    """``OUT/croissant.json``; its files (FileObjects) stated with their true sha256 and size,
    and its publication date a day mlcroissant reads without a warning."""
    doc = json.loads((out / "croissant.json").read_text(encoding="utf-8"))
    assert isinstance(doc, dict)
    objects = {d["contentUrl"]: d for d in doc["distribution"] if d["@type"] == "cr:FileObject"}
    assert sorted(objects) == sorted(data_file(c, s) for c in CONFIGS for s in SPLITS)
    for path, obj in objects.items():
        assert obj["encodingFormat"] == "application/x-parquet"
        assert obj["sha256"] == file_sha256(out / path)
        assert obj["contentSize"] == f"{(out / path).stat().st_size} B"
    # The day the tables were made: a date mlcroissant reads without a warning.
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", doc["datePublished"])
    return doc


def without_data_facts(doc: dict[str, Any]) -> dict[str, Any]:
    """The document without what states its data (checked by :func:`read_croissant` or
    made of the rows' counts): the files' sizes and checksums, the day the tables were made,
    the numbers in the description."""
    doc = dict(doc)
    doc["description"] = re.sub(r"\d+", "#", doc["description"])
    doc["datePublished"] = "#"
    doc["distribution"] = [
        {k: v for k, v in d.items() if k not in ("sha256", "contentSize")}
        for d in doc["distribution"]
    ]
    return doc


def assert_records_are_the_rows(out: Path, expected: Rows, configs: tuple[str, ...]) -> None:
    """``mlcroissant.Dataset(jsonld=OUT/croissant.json)`` validates without an error or a
    warning, its record sets are the configs, and ``records()`` of each of ``configs`` gives
    every row of the tables with its split (events: their column; points: their file), in
    the tables' order within a split, with the same values."""
    import mlcroissant as mlc

    dataset = mlc.Dataset(jsonld=out / "croissant.json")
    issues = dataset.metadata.ctx.issues
    assert not issues.errors, issues.report()
    assert not issues.warnings, issues.report()
    assert [rs.name for rs in dataset.metadata.record_sets] == list(CONFIGS)
    for config in configs:
        names = expected[config]["train"].column_names
        fields = [*names, "split"] if config == "event_points" else names
        columns: dict[str, list[Any]] = {name: [] for name in fields}
        for record in dataset.records(record_set=config):
            assert sorted(record) == sorted(f"{config}/{n}" for n in fields)
            for name in fields:
                columns[name].append(record[f"{config}/{name}"])
        split = column_values(columns["split"])
        for name in SPLITS:
            mine = np.flatnonzero(split == name)
            want = expected[config][name]
            assert mine.size == want.num_rows, (config, name)
            assert_same_rows(
                {n: [columns[n][i] for i in mine] for n in names}, want, f"croissant {config}"
            )


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_croissant_validates_and_its_records_are_the_tables_rows(
    exported: tuple[Path, ExportResult], expected: Rows, narrow: tuple[Path, Rows]
) -> None:
    """The shared export's ``croissant.json``: a Dataset of this version and licence; every
    Parquet file a FileObject with its true sha256 and size; valid for ``mlcroissant``
    (no error, no warning), whose ``records()`` of the events are the tables' rows (every
    one, with the model's scores and the split). The narrower export's: the same document
    but for its data's sizes, checksums and counts (each checked against its files), valid
    too, and ``records()`` of both configs give every row of its tables."""
    out, _ = exported
    doc = read_croissant(out)
    assert doc["@type"] == "sc:Dataset"
    assert doc["conformsTo"] == "http://mlcommons.org/croissant/1.0"
    assert doc["license"] == "https://creativecommons.org/licenses/by/4.0/"
    assert doc["version"] == __version__ and doc["name"] and doc["description"] and doc["url"]
    assert_records_are_the_rows(out, expected, ("events",))

    narrow_out, narrow_expected = narrow
    # Points in each split (so their records are read), fewer than the shared export's.
    for split in SPLITS:
        rows = narrow_expected["event_points"][split].num_rows
        assert 0 < rows < expected["event_points"][split].num_rows, split
    assert without_data_facts(read_croissant(narrow_out)) == without_data_facts(doc)
    assert_records_are_the_rows(narrow_out, narrow_expected, CONFIGS)

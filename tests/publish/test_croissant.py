"""The Croissant metadata (``croissant.json``) of ``terrain export``: valid for
``mlcroissant``, and its records are the tables' rows."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from tests.publish.exported import CONFIGS, SPLITS, assert_same_rows, column_values
from toolkit import __version__
from toolkit.manifest import file_sha256
from toolkit.publish.dataset import data_file
from toolkit.publish.export import ExportResult


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_croissant_validates_and_its_records_are_the_tables_rows(
    exported: tuple[Path, ExportResult], expected: dict[str, dict[str, pa.Table]]
) -> None:
    """``mlcroissant.Dataset(jsonld=OUT/croissant.json)`` validates without an error; every
    Parquet file is a FileObject with its true sha256 and size; ``records()`` of each record
    set gives every row of the tables with its split (events: their column; points: their
    file), in the tables' order within a split, with the same values."""
    import mlcroissant as mlc

    out, _ = exported
    doc = json.loads((out / "croissant.json").read_text(encoding="utf-8"))
    assert doc["@type"] == "sc:Dataset"
    assert doc["conformsTo"] == "http://mlcommons.org/croissant/1.0"
    assert doc["license"] == "https://creativecommons.org/licenses/by/4.0/"
    assert doc["version"] == __version__ and doc["name"] and doc["description"] and doc["url"]
    objects = {d["contentUrl"]: d for d in doc["distribution"] if d["@type"] == "cr:FileObject"}
    assert sorted(objects) == sorted(data_file(c, s) for c in CONFIGS for s in SPLITS)
    for path, obj in objects.items():
        assert obj["encodingFormat"] == "application/x-parquet"
        assert obj["sha256"] == file_sha256(out / path)
        assert obj["contentSize"] == f"{(out / path).stat().st_size} B"

    # The day the tables were made: a date mlcroissant reads without a warning.
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", doc["datePublished"])
    dataset = mlc.Dataset(jsonld=out / "croissant.json")
    issues = dataset.metadata.ctx.issues
    assert not issues.errors, issues.report()
    assert not issues.warnings, issues.report()
    assert [rs.name for rs in dataset.metadata.record_sets] == list(CONFIGS)
    for config in CONFIGS:
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

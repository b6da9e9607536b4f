"""``terrain export`` on the bundled sample log: the tables -> a dataset another team loads
with its own tools (Hugging Face ``datasets``, MLCommons ``mlcroissant``, polars, pyarrow).

The workspace is the pipeline run ``test_learn.py`` builds (label, tables, learn, evaluate on
the projected sample, once per session, see :func:`tests.stages.test_learn.build_pipeline`).
Every client must give back the tables exactly: per split, the same rows, in the tables'
order, with the same values (floats bit for bit). What each split must hold is derived
(``exported.py``, ``conftest.py``) from ``tables/events.parquet``,
``tables/event_points.parquet`` and ``report/scores.parquet`` independently of the export's
code. The dataset card and the Croissant metadata have their own files (``test_card.py``,
``test_croissant.py``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tests.publish.exported import (
    ARROW_TYPES,
    CONFIGS,
    POLARS_TYPES,
    SPLITS,
    assert_same_rows,
    card_header,
)
from tests.stages.test_learn import (
    Pipeline,
    copy_workspace,
    rewrite_events_table,
    with_rough,
    write_events_unrecorded,
)
from toolkit import __version__
from toolkit.atomic import host_name
from toolkit.config import PipelineConfig
from toolkit.errors import StageError, WorkspaceError
from toolkit.manifest import Manifest, file_sha256
from toolkit.publish import export as export_stage
from toolkit.publish.dataset import data_file, export_config_hash
from toolkit.publish.export import ExportResult, run_export
from toolkit.tableio import load_table_schema, read_table, read_table_metadata


def tree_digest(root: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under ``root``."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def leftovers(out: Path) -> list[str]:
    """Hidden directories an export to ``out`` may leave beside it."""
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


# -- the layout ---------------------------------------------------------------------------


def test_the_export_holds_the_card_the_croissant_and_one_file_per_config_and_split(
    exported: tuple[Path, ExportResult], expected: dict[str, dict[str, pa.Table]]
) -> None:
    """README.md, croissant.json and data/<config>/<split>-00000-of-00001.parquet, nothing
    else; the result's counts are the tables' and its summary says where and how many."""
    out, result = exported
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert files == sorted(
        ["README.md", "croissant.json", *(data_file(c, s) for c in CONFIGS for s in SPLITS)]
    )
    assert list(result.files) == files
    assert result.out_dir == out and result.scores and not result.warnings
    for split in SPLITS:
        events = expected["events"][split]
        counts = result.splits[split]
        assert counts.events == events.num_rows > 0
        assert counts.rough == sum(events.column("rough").to_pylist()) > 0
        assert counts.points == expected["event_points"][split].num_rows > 0
    summary = result.summary()
    assert "\n" not in summary and str(out) in summary
    for split in SPLITS:
        c = result.splits[split]
        assert f"{split} {c.events} events ({c.rough} rough), {c.points} point rows" in summary
    assert not leftovers(out)


# -- the clients ----------------------------------------------------------------------------


def test_polars_and_pyarrow_read_each_split_file_as_the_tables_hold_it(
    exported: tuple[Path, ExportResult],
    expected: dict[str, dict[str, pa.Table]],
    pipeline: Pipeline,
) -> None:
    """Each split file read by polars and by pyarrow: the schema's types exactly (string,
    int64, float64, bool; no dictionary or large types leaking out), the tables' rows in
    order, and the contract's key-value metadata (schema, toolkit version, the source log's
    sha256, config hash) plus which config and split the file is."""
    out, _ = exported
    manifest = Manifest(pipeline.ws.log_manifest_path(pipeline.log_id)).read()
    log_sha = manifest["source"]["sha256"]
    events_schema = load_table_schema("tables_events")
    scores_schema = load_table_schema("scores")
    types = {c.name: c.type for c in events_schema.columns}
    types.update({n: scores_schema.column(n).type for n in ("r_combined", "predicted")})
    types.update({c.name: c.type for c in load_table_schema("event_points").columns})
    for config in CONFIGS:
        for split in SPLITS:
            path = out / data_file(config, split)
            want = expected[config][split]

            frame = pl.read_parquet(path)
            assert frame.columns == want.column_names
            assert [frame.schema[n] for n in frame.columns] == [
                POLARS_TYPES[types[n]] for n in frame.columns
            ]
            assert_same_rows({n: frame[n] for n in frame.columns}, want, f"polars {path}")

            table = pq.read_table(path)
            assert [(f.name, f.type) for f in table.schema] == [
                (n, ARROW_TYPES[types[n]]) for n in want.column_names
            ]
            assert_same_rows(
                {n: table.column(n) for n in table.column_names}, want, f"pyarrow {path}"
            )
            meta = read_table_metadata(path)
            assert meta["schema_name"] == ("tables_events" if config == "events" else config)
            assert meta["toolkit_version"] == __version__
            assert meta["source_sha256"] == log_sha
            assert meta["config_hash"] == export_config_hash(pipeline.ws.read_config())
            assert meta["dataset_config"] == config and meta["dataset_split"] == split
            source = pipeline.ws.tables_dir / f"{config}.parquet"
            assert meta["tables_sha256"] == file_sha256(source)


# -- behaviour ------------------------------------------------------------------------------


def test_the_same_workspace_exports_the_same_bytes(
    exported: tuple[Path, ExportResult],
    pipeline: Pipeline,
    config: PipelineConfig,
    tmp_path: Path,
) -> None:
    """Another export of the same workspace, elsewhere: byte-identical files (no time, no
    path in any of them); replacing the first export with ``overwrite`` gives the same bytes
    again and leaves nothing beside it."""
    out, _ = exported
    again = tmp_path / "again"
    run_export(pipeline.ws, again, config)
    assert tree_digest(again) == tree_digest(out)

    run_export(pipeline.ws, again, config, overwrite=True)
    assert tree_digest(again) == tree_digest(out)
    assert not leftovers(again)


def test_a_non_empty_destination_is_refused_without_overwrite_and_left_as_it_was(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path
) -> None:
    """An existing folder with files in it: StageError naming it, in one line, and the
    folder untouched. With ``overwrite``, only an earlier export is replaced, never a folder
    of other files; the workspace itself (or a folder holding it) never."""
    out = tmp_path / "taken"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    before = tree_digest(out)
    with pytest.raises(StageError, match="exists and is not empty") as err:
        run_export(pipeline.ws, out, config)
    assert err.value.path == out and "\n" not in str(err.value)
    assert tree_digest(out) == before and not leftovers(out)

    with pytest.raises(StageError, match="not an earlier export") as err:
        run_export(pipeline.ws, out, config, overwrite=True)
    assert tree_digest(out) == before and not leftovers(out)

    for target in (pipeline.ws.root, pipeline.ws.root.parent):
        with pytest.raises(StageError, match="holds the workspace"):
            run_export(pipeline.ws, target, config, overwrite=True)
    assert pipeline.ws.events_table.is_file()

    # An empty folder is as good as none.
    empty = tmp_path / "empty"
    empty.mkdir()
    run_export(pipeline.ws, empty, config)
    assert (empty / "croissant.json").is_file()

    # An earlier export with another team's file beside it is not replaced: the file would
    # be deleted with it.
    (empty / "data" / "theirs.csv").write_text("theirs\n")
    before = tree_digest(empty)
    with pytest.raises(StageError, match="holds data/theirs.csv, which no export wrote"):
        run_export(pipeline.ws, empty, config, overwrite=True)
    assert tree_digest(empty) == before
    (empty / "data" / "theirs.csv").unlink()
    run_export(pipeline.ws, empty, config, overwrite=True)  # only its own files: replaced

    # Nowhere inside a workspace: it would pass for a log, or replace the workspace's files.
    for inside in (pipeline.ws.logs_dir / "extra", pipeline.ws.root / "dataset"):
        with pytest.raises(WorkspaceError, match="lies inside the workspace"):
            run_export(pipeline.ws, inside, config)
        assert not inside.exists()


def test_a_failure_leaves_no_export_and_nothing_beside_it(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The export fails after its Parquet files are written: no OUT, nothing hidden beside
    it; an earlier export being replaced stays whole. A hidden directory a killed export
    left (its process gone) is removed by the next one."""
    out = tmp_path / "dataset"

    def broken(_: object) -> dict[str, Any]:
        raise OSError("disk full")

    monkeypatch.setattr(export_stage, "croissant_metadata", broken)
    with pytest.raises(OSError, match="disk full"):
        run_export(pipeline.ws, out, config)
    assert not out.exists() and not leftovers(out)
    monkeypatch.undo()

    run_export(pipeline.ws, out, config)
    before = tree_digest(out)
    monkeypatch.setattr(export_stage, "croissant_metadata", broken)
    with pytest.raises(OSError, match="disk full"):
        run_export(pipeline.ws, out, config, overwrite=True)
    assert tree_digest(out) == before and not leftovers(out)
    monkeypatch.undo()

    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    pid = int(dead.stdout)
    stale = tmp_path / f".{out.name}.{host_name()}-{pid}-0123456789ab.export"
    (stale / "data").mkdir(parents=True)
    run_export(pipeline.ws, out, config, overwrite=True)
    assert not stale.exists() and tree_digest(out) == before


def test_tables_not_written_by_terrain_tables_are_refused(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path
) -> None:
    """Tables changed after the last finished ``terrain tables`` (here the events rewritten
    without a row), or never made: one-line errors naming the file and the verb to run; no
    export is made."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    write_events_unrecorded(ws, read_table(ws.events_table, "tables_events").slice(1))
    out = tmp_path / "dataset"
    with pytest.raises(WorkspaceError, match="run `terrain tables` again") as err:
        run_export(ws, out, config)
    assert err.value.path == ws.events_table and "\n" not in str(err.value)
    assert not out.exists() and not leftovers(out)

    ws.event_points_table.unlink()
    with pytest.raises(StageError, match="run `terrain tables` first") as err:
        run_export(ws, out, config)
    assert err.value.path == ws.event_points_table
    assert not out.exists()


def test_tables_of_another_configuration_or_label_rule_are_refused(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path
) -> None:
    """The card states the threshold and the split from the configuration: tables made with
    another one, or whose rough labels are not ``ruggedness >= threshold``, are refused
    (one line naming the file) rather than described wrongly."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    out = tmp_path / "dataset"
    other = dataclasses.replace(
        config, tables=dataclasses.replace(config.tables, train_fraction=0.6)
    )
    with pytest.raises(WorkspaceError, match="tables outputs are stale .made with another") as err:
        run_export(ws, out, other)
    assert err.value.path == ws.tables_dir

    relabelled = dataclasses.replace(
        config, label=dataclasses.replace(config.label, rough_threshold_g_per_mph=0.5)
    )
    with pytest.raises(StageError, match="labelled with another configuration"):
        run_export(ws, out, relabelled)

    events = read_table(ws.events_table, "tables_events")
    rough = np.asarray(events.column("rough").to_pylist(), dtype=bool)
    flipped = rough.copy()
    flipped[0] = not flipped[0]
    rewrite_events_table(ws, with_rough(events, flipped))
    with pytest.raises(StageError, match="rough label is not ruggedness >=") as err:
        run_export(ws, out, config)
    assert err.value.path == ws.events_table
    assert not out.exists()


def test_scores_of_other_tables_are_left_out_with_a_warning(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path
) -> None:
    """The model's scores are optional: after the tables change (one event's end time moved
    by 1 ns, recorded as a finished tables run), ``report/scores.parquet`` scored other
    tables, so the events go out without ``r_combined`` and ``predicted`` (card and features
    say nothing of them) and the result warns why."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    events = read_table(ws.events_table, "tables_events")
    t_end = events.column("t_end_ns").to_numpy().copy()
    t_end[0] += 1
    i = events.schema.get_field_index("t_end_ns")
    rewrite_events_table(ws, events.set_column(i, "t_end_ns", pa.array(t_end, pa.int64())))
    out = tmp_path / "dataset"
    result = run_export(ws, out, config)
    assert not result.scores
    assert len(result.warnings) == 1 and "scores" in result.warnings[0]
    names = load_table_schema("tables_events").column_names
    for split in SPLITS:
        assert pq.read_schema(out / data_file("events", split)).names == list(names)
    info = {i["config_name"]: i for i in card_header(out)["dataset_info"]}
    assert [f["name"] for f in info["events"]["features"]] == list(names)
    assert "r_combined" not in (out / "README.md").read_text(encoding="utf-8")
    assert "r_combined" not in (out / "croissant.json").read_text(encoding="utf-8")


def test_a_workspace_without_a_report_exports_without_scores(
    pipeline: Pipeline, config: PipelineConfig, tmp_path: Path
) -> None:
    """No ``report/scores.parquet`` (learn and evaluate never ran): the export is the tables
    alone, quietly."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    ws.scores_table.unlink()
    result = run_export(ws, tmp_path / "dataset", config)
    assert not result.scores and not result.warnings
    assert os.path.isfile(tmp_path / "dataset" / "croissant.json")

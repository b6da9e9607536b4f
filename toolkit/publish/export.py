"""``terrain export``: the training and test tables -> a labelled dataset another team can
load knowing nothing of this toolkit (Hugging Face ``datasets`` layout, a dataset card,
Croissant metadata). Not a pipeline stage: a command over a finished workspace, reading
what ``terrain tables`` (and ``evaluate``) wrote and changing nothing of it. The manual,
with what each file holds and where its rows come from, is ``docs/export.md``."""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit.atomic import atomic_write_text, fsync_dir, temp_path_beside
from toolkit.config import PipelineConfig
from toolkit.errors import StageError, WorkspaceError
from toolkit.layout import LogFiles
from toolkit.manifest import Manifest, StageRecord, file_sha256, require_finished
from toolkit.publish.card import dataset_card
from toolkit.publish.croissant import croissant_metadata
from toolkit.publish.dataset import (
    EVENT_POINTS,
    EVENTS,
    POINT_COLUMNS,
    SCORE_COLUMNS,
    SPLITS,
    DatasetFacts,
    LogSource,
    Scores,
    data_file,
    dataset_columns,
    export_config_hash,
)
from toolkit.publish.destination import check_destination, publish, remove_dead_temp_dirs
from toolkit.sim.record import SIM_RECORD
from toolkit.stages import label as label_stage
from toolkit.stages import tables as tables_stage
from toolkit.stages.tables import SplitTotals
from toolkit.stages.training_data import table_inputs
from toolkit.tableio import TableWriter, iter_table_batches, load_table_schema, read_table
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

#: Rows per batch when streaming the event points.
POINT_BATCH = 1_048_576
#: Low-cardinality string columns read as dictionaries (a few distinct values each).
DICTIONARY_COLUMNS = ("log_id", "wheel", "laser")


@dataclass(frozen=True)
class ExportResult:
    """What :func:`run_export` wrote."""

    out_dir: Path
    splits: dict[str, SplitTotals]
    logs: tuple[str, ...]
    #: Whether the events carry the model's ``r_combined`` and ``predicted``.
    scores: bool
    #: Every file written, relative to ``out_dir``, sorted.
    files: tuple[str, ...]
    seconds: float
    warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        """Where the dataset went and what each split holds."""
        parts = [
            f"{name} {c.events} events ({c.rough} rough), {c.points} point rows"
            for name, c in self.splits.items()
        ]
        scored = "; with the model's scores" if self.scores else ""
        return (
            f"dataset exported to {self.out_dir} from {len(self.logs)} log(s): "
            + "; ".join(parts)
            + scored
        )


# --------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise WorkspaceError(f"cannot read: {exc.strerror or exc}", path=path) from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise WorkspaceError(f"not valid JSON: {exc}", path=path) from exc


def log_source(workspace: Workspace, log_id: str, config: PipelineConfig) -> LogSource:
    """A log's provenance from its manifest and ``mcap_metadata.json``; its events must
    have been labelled with this configuration (the card states the label's definition)."""
    log_dir = workspace.log_dir(log_id)
    manifest_path = log_dir / Workspace.MANIFEST_NAME
    if not manifest_path.is_file():
        raise WorkspaceError(
            f"log {log_id} of the tables has no manifest; run `terrain ingest` on it again",
            path=manifest_path,
        )
    manifest = Manifest(manifest_path)
    doc = manifest.read()
    source = doc.get("source")
    if not isinstance(source, dict) or not source.get("sha256"):
        raise WorkspaceError(
            "no source log recorded (path and sha256); run `terrain ingest` on it again",
            path=manifest_path,
        )
    labelled = manifest.stage(label_stage.STAGE)
    if labelled is None or labelled.config_hash != label_stage.SPEC.config_hash(config):
        raise StageError(
            f"log {log_id}: its events were labelled with another configuration than the "
            "workspace's (or not at all); run `terrain label` and `terrain tables` again",
            path=manifest_path,
        )
    sim: Mapping[str, Any] | None = None
    meta_path = LogFiles(log_dir).mcap_metadata
    if meta_path.is_file():
        meta = read_json(meta_path)
        if isinstance(meta, dict) and isinstance(meta.get(SIM_RECORD), dict):
            sim = meta[SIM_RECORD]
    header = {k: doc[k] for k in ("label", "pose", "pose_accuracy") if isinstance(doc.get(k), dict)}
    return LogSource(
        log_id=log_id,
        file_name=Path(str(source.get("path", ""))).name or "(unknown)",
        sha256=str(source["sha256"]),
        size_bytes=int(source.get("size_bytes", 0)),
        sim=sim,
        header=header,
    )


def read_events(workspace: Workspace) -> pa.Table:
    """The tables' events, the schema's columns in its order."""
    schema = load_table_schema("tables_events")
    events = read_table(workspace.events_table, "tables_events", columns=schema.column_names)
    if events.num_rows == 0:
        raise StageError(
            "the tables hold no event: nothing to export (see `terrain label`)",
            path=workspace.events_table,
        )
    return events


def check_labels(events: pa.Table, config: PipelineConfig, path: Path) -> None:
    """StageError unless every ``rough`` is ``ruggedness >= threshold``: the card defines it
    so, and a table labelled by another rule must not go out under that definition."""
    ruggedness = events.column("ruggedness").to_numpy()
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    expected = ruggedness >= config.label.rough_threshold_g_per_mph
    disagree = int(np.count_nonzero(rough != expected))
    if disagree:
        raise StageError(
            f"{disagree} event(s) whose rough label is not ruggedness >= "
            f"{config.label.rough_threshold_g_per_mph:g} G/mph; run `terrain label` and "
            "`terrain tables` again",
            path=path,
        )


def event_keys(events: pa.Table, log_ids: Sequence[str]) -> NDArray[np.int64]:
    """One int64 per event: ``log index * (largest event id + 1) + event_id``."""
    code = {log_id: i for i, log_id in enumerate(log_ids)}
    logs = np.array([code[v] for v in events.column("log_id").to_pylist()], dtype=np.int64)
    ids = events.column("event_id").to_numpy().astype(np.int64)
    keys: NDArray[np.int64] = logs * (int(ids.max()) + 1) + ids
    return keys


def model_scores(
    workspace: Workspace, tables: Mapping[str, str], events: pa.Table
) -> tuple[Scores | None, list[str]]:
    """The model's ``r_combined`` and ``predicted`` per event, when ``report/scores.parquet``
    is what the last finished ``terrain evaluate`` wrote from these tables; None (and why,
    as a warning) when it scored other tables; None quietly when there is none."""
    path = workspace.scores_table
    if not path.is_file():
        return None, []
    record = workspace.manifest().stage("evaluate")
    require_finished(record, "evaluate", {path.name: file_sha256(path)}, workspace.report_dir)
    assert record is not None  # require_finished refuses a missing record
    stale = sorted(k for k, sha in tables.items() if record.inputs.get(k) != sha)
    if stale:
        return None, [
            f"{path}: scored other tables than these ({', '.join(stale)}); the model's scores "
            "are left out (run `terrain learn` and `terrain evaluate` to include them)"
        ]
    scores = read_table(path, "scores", columns=["log_id", "event_id", *SCORE_COLUMNS])
    by_key = {
        (log_id, event_id): row
        for row, (log_id, event_id) in enumerate(
            zip(
                scores.column("log_id").to_pylist(),
                scores.column("event_id").to_pylist(),
                strict=True,
            )
        )
    }
    rows = [
        by_key.get((log_id, event_id))
        for log_id, event_id in zip(
            events.column("log_id").to_pylist(), events.column("event_id").to_pylist(), strict=True
        )
    ]
    if any(r is None for r in rows) or len(by_key) != scores.num_rows:
        return None, [
            f"{path}: does not score every event of the tables once; the model's scores are "
            "left out (run `terrain evaluate` again to include them)"
        ]
    take = pa.array(rows, pa.int64())
    mu: float | None = None
    model_sha = record.inputs.get("model")  # evaluate's needs, by layout name
    # mu is quoted only from the model that was scored (model.json may have been relearned).
    if (
        model_sha
        and workspace.model_path.is_file()
        and file_sha256(workspace.model_path) == model_sha
    ):
        doc = read_json(workspace.model_path)
        value = doc.get("mu") if isinstance(doc, dict) else None
        mu = float(value) if isinstance(value, int | float) else None
    return (
        Scores(
            pc.take(scores.column("r_combined"), take).combine_chunks(),
            pc.take(scores.column("predicted"), take).combine_chunks(),
            mu,
        ),
        [],
    )


# --------------------------------------------------------------------------------------
# The Parquet files
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Provenance:
    """What every exported Parquet file is stamped with: the source logs' sha256, the
    export's configuration hash (the contract's keys), and which config, split and table of
    the workspace it holds."""

    source_sha256: tuple[str, ...]
    config_hash: str
    #: sha256 of the workspace's tables, keyed by layout name (``events_table``...).
    tables: Mapping[str, str]

    def writer(self, tmp: Path, config_name: str, split: str, schema: str) -> TableWriter:
        return TableWriter(
            tmp / data_file(config_name, split),
            schema,
            source_sha256=self.source_sha256,
            config_hash=self.config_hash,
            extra_metadata={
                "dataset_config": config_name,
                "dataset_split": split,
                "tables_sha256": self.tables[f"{config_name}_table"],
            },
        )


def _write_events(
    tmp: Path,
    events: pa.Table,
    scores: Scores | None,
    provenance: _Provenance,
) -> dict[str, pa.Table]:
    """The events files, one per split; returns each split's events as written."""
    if scores is not None:
        events = events.append_column("r_combined", scores.r_combined).append_column(
            "predicted", scores.predicted
        )
    out: dict[str, pa.Table] = {}
    writers = [provenance.writer(tmp, EVENTS, split, "tables_events") for split in SPLITS]
    try:
        for split, writer in zip(SPLITS, writers, strict=True):
            part = events.filter(pc.equal(events.column("split"), split))
            writer.write(part)
            writer.finish()
            out[split] = part
        for writer in writers:
            writer.publish()
    except BaseException:
        for writer in writers:
            writer.abort()
        raise
    return out


def _write_points(
    tmp: Path,
    workspace: Workspace,
    events: pa.Table,
    log_ids: Sequence[str],
    provenance: _Provenance,
) -> dict[str, tuple[int, int]]:
    """The event points, streamed into one file per split (the split of each row's event),
    in the tables' order; returns the rows and their Arrow size (bytes) per split."""
    keys = event_keys(events, log_ids)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    is_train = np.asarray(events.column("split").to_pylist(), dtype=object) == "train"
    train_sorted = is_train[order]
    code = {log_id: i for i, log_id in enumerate(log_ids)}
    width = int(events.column("event_id").to_numpy().max()) + 1
    path = workspace.event_points_table
    writers = {
        split: provenance.writer(tmp, EVENT_POINTS, split, "event_points") for split in SPLITS
    }
    rows = dict.fromkeys(SPLITS, 0)
    nbytes = dict.fromkeys(SPLITS, 0)
    # The rows as the files hold them (plain strings, not the dictionaries read): cast here
    # rather than in the writer, so their Arrow size can be counted.
    schema = load_table_schema("event_points").arrow_schema().remove_metadata()
    try:
        for batch in iter_table_batches(
            path,
            "event_points",
            columns=POINT_COLUMNS,
            batch_rows=POINT_BATCH,
            as_dictionary=DICTIONARY_COLUMNS,
        ):
            table = pa.Table.from_batches([batch]).select(list(POINT_COLUMNS)).cast(schema)
            logs = batch.column("log_id")
            # The dictionary's few values looked up once, then spread by their indices.
            values = np.array(
                [code.get(v, -1) for v in logs.dictionary.to_pylist()], dtype=np.int64
            )
            log_code = values[logs.indices.to_numpy(zero_copy_only=False)]
            event_id = batch.column("event_id").to_numpy().astype(np.int64)
            key = log_code * width + event_id
            at = np.minimum(np.searchsorted(sorted_keys, key), sorted_keys.size - 1)
            known = (
                (log_code >= 0) & (event_id >= 0) & (event_id < width) & (sorted_keys[at] == key)
            )
            if not known.all():
                bad = int(np.flatnonzero(~known)[0])
                raise StageError(
                    f"a point row of event {int(event_id[bad])} of log "
                    f"{logs[bad].as_py()} that tables/events.parquet does not hold; run "
                    "`terrain tables` again",
                    path=path,
                )
            train = train_sorted[at]
            for split, mask in (("train", train), ("test", ~train)):
                if mask.any():
                    part = table if mask.all() else table.filter(pa.array(mask))
                    writers[split].write(part)
                    rows[split] += part.num_rows
                    nbytes[split] += arrow_bytes(part)
        for writer in writers.values():
            writer.finish()
        for writer in writers.values():
            writer.publish()
    except BaseException:
        for writer in writers.values():
            writer.abort()
        raise
    return {split: (rows[split], nbytes[split]) for split in SPLITS}


def arrow_bytes(table: pa.Table) -> int:
    """The size of ``table``'s rows in Arrow's memory layout, as a reader of the file holds
    them: a column without nulls has no validity bitmap (a cast from a dictionary leaves
    one). What ``datasets`` records as a split's ``num_bytes``, to within the few bytes of
    string offsets that depend on how the rows are batched."""
    total = 0
    for column in table.columns:
        for chunk in column.chunks:
            buffers = chunk.buffers()
            if chunk.null_count == 0:
                buffers = buffers[1:]
            total += sum(b.size for b in buffers if b is not None)
    return total


def _check_point_rows(events: Mapping[str, pa.Table], rows: Mapping[str, int], path: Path) -> None:
    """StageError unless each split's point rows are what its events say they have under
    their tyres (``points_left + points_right``): a points table from another tables run."""
    for split in SPLITS:
        part = events[split]
        expected = int(pc.sum(part.column("points_left")).as_py() or 0) + int(
            pc.sum(part.column("points_right")).as_py() or 0
        )
        if rows[split] != expected:
            raise StageError(
                f"{rows[split]} point rows for the {split} split, but tables/events.parquet "
                f"counts {expected} under its tyres; run `terrain tables` again",
                path=path,
            )


# --------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------


def _fsync_tree(directory: Path) -> None:
    """fsync every directory of the export (its files were fsynced by their writers), so
    the rename that publishes it cannot survive a power cut without its contents."""
    for root, _dirs, _files in os.walk(directory):
        fsync_dir(Path(root))


@dataclass(frozen=True)
class _Inputs:
    """What the export is made from, read and checked before anything is written."""

    #: sha256 of the workspace's tables, keyed by layout name (``events_table``...).
    tables: Mapping[str, str]
    #: The record of the ``terrain tables`` run that wrote them.
    record: StageRecord
    events: pa.Table
    #: The logs of the events, in the order of their first event.
    log_ids: tuple[str, ...]
    sources: tuple[LogSource, ...]
    scores: Scores | None
    #: Why the model's scores are left out, when they are.
    warnings: tuple[str, ...]


def _read_inputs(workspace: Workspace, config: PipelineConfig) -> _Inputs:
    """The tables as the last finished ``terrain tables`` wrote them with this
    configuration, their logs' provenance and the model's scores; a StageError or
    WorkspaceError when they cannot be exported."""
    tables = table_inputs(workspace, config)
    record = workspace.manifest().stage(tables_stage.STAGE)
    assert record is not None  # table_inputs refuses a missing record
    events = read_events(workspace)
    log_ids = tuple(dict.fromkeys(events.column("log_id").to_pylist()))
    # Each log's labelling configuration first: a threshold changed since is the likelier
    # cause of labels that disagree with it, and the more useful message.
    sources = tuple(log_source(workspace, log_id, config) for log_id in log_ids)
    check_labels(events, config, workspace.events_table)
    scores, warnings = model_scores(workspace, tables, events)
    return _Inputs(tables, record, events, log_ids, sources, scores, tuple(warnings))


def _write_dataset(
    tmp: Path, workspace: Workspace, config: PipelineConfig, inputs: _Inputs
) -> DatasetFacts:
    """Write every file of the export into the directory ``tmp``: the Parquet files, then
    the card and the Croissant metadata stating what they hold."""
    provenance = _Provenance(
        tuple(s.sha256 for s in inputs.sources), export_config_hash(config), inputs.tables
    )
    by_split = _write_events(tmp, inputs.events, inputs.scores, provenance)
    written = _write_points(tmp, workspace, inputs.events, inputs.log_ids, provenance)
    points = {split: rows for split, (rows, _) in written.items()}
    _check_point_rows(by_split, points, workspace.event_points_table)
    in_memory = {
        **{data_file(EVENTS, split): arrow_bytes(by_split[split]) for split in SPLITS},
        **{data_file(EVENT_POINTS, split): size for split, (_, size) in written.items()},
    }
    files = {
        data_file(name, split): (
            (tmp / data_file(name, split)).stat().st_size,
            file_sha256(tmp / data_file(name, split)),
        )
        for name in (EVENTS, EVENT_POINTS)
        for split in SPLITS
    }
    facts = DatasetFacts(
        config=config,
        sources=inputs.sources,
        events=by_split,
        points=points,
        files=files,
        arrow_bytes=in_memory,
        columns=dataset_columns(inputs.scores),
        scores=inputs.scores,
        tables=inputs.tables,
        tables_counts=dict(inputs.record.row_counts),
        tables_rejects=dict(inputs.record.rejects),
        tables_finished_utc=inputs.record.finished_utc,
    )
    atomic_write_text(tmp / "README.md", dataset_card(facts))
    atomic_write_text(
        tmp / "croissant.json",
        json.dumps(croissant_metadata(facts), indent=2, ensure_ascii=False, allow_nan=False) + "\n",
    )
    return facts


def run_export(
    workspace: Workspace, out_dir: Path, config: PipelineConfig, *, overwrite: bool = False
) -> ExportResult:
    """Write the dataset of the workspace's tables to ``out_dir`` (``docs/export.md``): in a
    hidden directory beside it, put in place only when complete."""
    start = time.perf_counter()
    out_dir = Path(os.path.abspath(out_dir))
    check_destination(workspace, out_dir, overwrite)
    inputs = _read_inputs(workspace, config)
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WorkspaceError(f"cannot create: {exc.strerror or exc}", out_dir.parent) from exc
    remove_dead_temp_dirs(out_dir)
    tmp = temp_path_beside(out_dir, "export")
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise WorkspaceError(f"cannot create: {exc.strerror or exc}", tmp) from exc
        facts = _write_dataset(tmp, workspace, config, inputs)
        _fsync_tree(tmp)
        publish(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for warning in inputs.warnings:
        _log.warning("%s", warning)
    return ExportResult(
        out_dir=out_dir,
        splits=facts.counts(),
        logs=inputs.log_ids,
        scores=inputs.scores is not None,
        files=tuple(sorted([*facts.files, "README.md", "croissant.json"])),
        seconds=time.perf_counter() - start,
        warnings=inputs.warnings,
    )


__all__ = ["ExportResult", "arrow_bytes", "run_export"]

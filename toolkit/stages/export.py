"""Export stage: the training and test tables -> a labelled dataset another team can load
knowing nothing of this toolkit.

What a reader gets
==================

The dataset is a folder in the layout of the Hugging Face ``datasets`` library, described a
second time, machine-readably, in MLCommons Croissant 1.0::

    OUT/README.md                                    the dataset card
    OUT/croissant.json                               Croissant 1.0 metadata (JSON-LD)
    OUT/data/events/train-00000-of-00001.parquet     one row per labelled event
    OUT/data/events/test-00000-of-00001.parquet
    OUT/data/event_points/train-00000-of-00001.parquet   one row per (laser point, event, tyre)
    OUT/data/event_points/test-00000-of-00001.parquet

Two *configs* (``events``, ``event_points``), each with a ``train`` and a ``test`` *split*, one
Parquet file per split (``<split>-<shard>-of-<shards>.parquet`` is the name the Hub's own
conversions use). The card's YAML header maps every config's splits to their files
(``configs: data_files``) and lists each config's columns with their types (``dataset_info:
features``), so ``datasets.load_dataset(OUT, "events")`` needs nothing else; Croissant
names every file with its sha256 and describes each config as a *record set* whose fields
are the Parquet columns.

Where the rows come from
========================

``events`` is ``WS/tables/events.parquet`` (schema ``tables_events``: the event, its shock,
speed, ruggedness and ``rough`` label, its split and the points under each tyre), split by its
``split`` column; when ``terrain evaluate`` has scored these very tables, the learned model's
``r_combined`` and ``predicted`` are added (the card says so). ``event_points`` is
``WS/tables/event_points.parquet`` (the paper's ``L_i = [x, y, z, tau, gamma, psi]`` of the
points under each rear tyre, with the log, event, tyre, laser and time), each row in the
split of its event. Within a split, rows keep the tables' order.

The tables are taken only as the last finished ``terrain tables`` wrote them, and only with
the configuration they were made with (the card states the label's threshold and the
split's fraction from it); every number of the card is counted from the rows written, the
workspace's manifests or ``mcap_metadata.json`` (whether a log is simulated).

All or nothing
==============

Everything is written into a hidden directory beside ``OUT`` and renamed into place once
complete, so a reader never finds half an export. ``OUT`` must not exist or be empty; with
``overwrite``, an earlier export there is swapped for the new one in one atomic exchange
(Linux ``renameat2``; elsewhere two renames, with a moment when ``OUT`` is absent). Only an
earlier export (a folder holding ``croissant.json`` and ``README.md``) is ever replaced, never
another folder of files, nor the workspace or a folder holding it. The same workspace gives
the same bytes: no file holds a time other than the data's, nor the path it was written to.

Croissant, record by record: a ``FileObject`` per Parquet file (its sha256 and size), a
``FileSet`` per config (``data/<config>/*.parquet``) that the config's ``RecordSet`` reads,
each field a column (``extract: column``); the points' ``split`` field is their file's name
(``extract: fileProperty fullpath`` and a regex), the events' their own column. Croissant's
``url`` is ``README.md``: where the dataset will be published is not known here.
"""

from __future__ import annotations

import json
import logging
import os
import re
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

from toolkit import __version__
from toolkit.atomic import (
    atomic_write_text,
    exchange_paths,
    fsync_dir,
    host_name,
    temp_path_beside,
)
from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import StageError, WorkspaceError
from toolkit.model.patches import POINT_COLUMNS as EVENT_POINT_COLUMNS
from toolkit.sim.record import SIM_RECORD
from toolkit.stages import label as label_stage
from toolkit.stages import tables as tables_stage
from toolkit.stages.learn import table_inputs
from toolkit.tableio import (
    ColumnSpec,
    TableWriter,
    iter_table_batches,
    load_table_schema,
    read_table,
)
from toolkit.workspace import (
    Manifest,
    Workspace,
    file_sha256,
    refuse_inside_workspace,
    require_finished,
)

_log = logging.getLogger(__name__)

STAGE = "export"
#: The configuration sections the dataset's contents and card depend on: the label's
#: definition, the split, the tyre window and the vehicle (the tyre tracks).
CONFIG_SECTIONS = ("label", "tables", "model", "vehicle")
SPLITS = ("train", "test")
EVENTS = "events"
EVENT_POINTS = "event_points"
LICENSE = "cc-by-4.0"
PRETTY_NAME = "Self-supervised terrain roughness: shock-labelled events and laser points"
DATASET_NAME = "terrain-roughness-self-supervised"
#: The columns of a point row, in order (the ``event_points`` schema's, as the model reads them).
POINT_COLUMNS = EVENT_POINT_COLUMNS
#: The model's columns added to the events when ``report/scores.parquet`` scored these tables.
SCORE_COLUMNS = ("r_combined", "predicted")
#: Rows per batch when streaming the event points.
POINT_BATCH = 1_048_576
#: Low-cardinality string columns read as dictionaries (a few distinct values each).
DICTIONARY_COLUMNS = ("log_id", "wheel", "laser")
#: Column type (the schemas' names) -> (``datasets`` dtype, Croissant dataType). The schema
#: names and the ``datasets`` dtypes coincide; Croissant's are schema.org's.
TYPES: dict[str, tuple[str, str]] = {
    "string": ("string", "sc:Text"),
    "int64": ("int64", "sc:Integer"),
    "float64": ("float64", "sc:Float"),
    "bool": ("bool", "sc:Boolean"),
}
#: The paper's training set (sect. 7: miles 60-70): laser points and events, for the card's
#: comparison of point density.
PAPER_TRAIN_POINTS = 887_878
PAPER_TRAIN_EVENTS = 11_470
#: The paper's share of rough events (sect. 7: 42 of 11,470 training, 58 of 13,325 test).
PAPER_ROUGH = ((42, 11_470), (58, 13_325))
CITATION = """@inproceedings{stavens2006selfsupervised,
  title     = {A Self-Supervised Terrain Roughness Estimator for Off-Road Autonomous Driving},
  author    = {Stavens, David and Thrun, Sebastian},
  booktitle = {Proceedings of the 22nd Conference on Uncertainty in Artificial Intelligence (UAI)},
  year      = {2006}
}"""
#: Croissant 1.0's JSON-LD context, as the specification's examples give it, with the two terms
#: later 1.0 tooling (mlcroissant) also declares, ``equivalentProperty`` and
#: ``samplingRate``: without them mlcroissant warns that the context is not the standard one.
CROISSANT_CONTEXT: dict[str, Any] = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "equivalentProperty": "cr:equivalentProperty",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "samplingRate": "cr:samplingRate",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}
CROISSANT_CONFORMS_TO = "http://mlcommons.org/croissant/1.0"
#: The hidden directory an export is written in: ``.<OUT name>.<host>-<pid>-<random>.export``.
_TEMP_DIR = re.compile(r"^\.(?P<name>.+)\.(?P<host>[^.]+)-(?P<pid>\d+)-[0-9a-f]{12}\.export$")


def data_file(config_name: str, split: str) -> str:
    """The path of one split's Parquet file, relative to the export's root."""
    return f"data/{config_name}/{split}-00000-of-00001.parquet"


def stage_config_hash(config: PipelineConfig) -> str:
    """The hash of the configuration sections the export depends on (in every file's
    metadata)."""
    return config_hash(config, sections=CONFIG_SECTIONS)


@dataclass(frozen=True)
class SplitCounts:
    """What one split of the export holds."""

    events: int
    rough: int
    points: int


@dataclass(frozen=True)
class ExportResult:
    """What :func:`run_export` wrote."""

    out_dir: Path
    splits: dict[str, SplitCounts]
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


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise WorkspaceError(f"cannot read: {exc.strerror or exc}", path=path) from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise WorkspaceError(f"not valid JSON: {exc}", path=path) from exc


def _log_source(workspace: Workspace, log_id: str, config: PipelineConfig) -> LogSource:
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
    if labelled is None or labelled.config_hash != label_stage.stage_config_hash(config):
        raise StageError(
            f"log {log_id}: its events were labelled with another configuration than the "
            "workspace's (or not at all); run `terrain label` and `terrain tables` again",
            path=manifest_path,
        )
    sim: Mapping[str, Any] | None = None
    meta_path = log_dir / "mcap_metadata.json"
    if meta_path.is_file():
        meta = _read_json(meta_path)
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


def _read_events(workspace: Workspace) -> pa.Table:
    """The tables' events, the schema's columns in its order."""
    schema = load_table_schema("tables_events")
    events = read_table(workspace.events_table, "tables_events", columns=schema.column_names)
    if events.num_rows == 0:
        raise StageError(
            "the tables hold no event: nothing to export (see `terrain label`)",
            path=workspace.events_table,
        )
    return events


def _check_labels(events: pa.Table, config: PipelineConfig, path: Path) -> None:
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


def _event_keys(events: pa.Table, log_ids: Sequence[str]) -> NDArray[np.int64]:
    """One int64 per event: ``log index * (largest event id + 1) + event_id``."""
    code = {log_id: i for i, log_id in enumerate(log_ids)}
    logs = np.array([code[v] for v in events.column("log_id").to_pylist()], dtype=np.int64)
    ids = events.column("event_id").to_numpy().astype(np.int64)
    keys: NDArray[np.int64] = logs * (int(ids.max()) + 1) + ids
    return keys


def _model_scores(
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
    model_sha = record.inputs.get("model.json")
    # mu is quoted only from the model that was scored (model.json may have been relearned).
    if (
        model_sha
        and workspace.model_path.is_file()
        and file_sha256(workspace.model_path) == model_sha
    ):
        doc = _read_json(workspace.model_path)
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
# The destination
# --------------------------------------------------------------------------------------


def _check_destination(workspace: Workspace, out_dir: Path, overwrite: bool) -> None:
    """Refuse a destination the export may not take (before anything is read or written)."""
    if out_dir.is_symlink():
        raise StageError("is a symbolic link; give the directory itself", path=out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise StageError("exists and is not a directory", path=out_dir)
    root = Path(os.path.realpath(workspace.root))
    real = Path(os.path.realpath(out_dir))
    if real == root or real in root.parents:
        # Replacing it would delete the workspace the export is made from.
        raise StageError(f"holds the workspace {workspace.root}; export elsewhere", path=out_dir)
    refuse_inside_workspace(out_dir)
    if not _nonempty(out_dir):
        return
    if not overwrite:
        raise StageError(
            "exists and is not empty; choose a new directory or use --overwrite to replace "
            "the export there",
            path=out_dir,
        )
    # --overwrite replaces an earlier export, never an arbitrary folder of someone's files:
    # every file there must be one the export wrote (its card, its Croissant metadata and
    # the data files that metadata lists).
    foreign = _not_written_by_export(out_dir)
    if foreign is not None:
        raise StageError(
            f"holds {foreign}, which no export wrote; refusing to replace it, choose a new "
            "or empty directory",
            path=out_dir,
        )


def _not_written_by_export(out_dir: Path) -> str | None:
    """The first file or folder in ``out_dir`` (relative) that an export did not write, or
    None when the folder is an earlier export and nothing else: ``README.md``,
    ``croissant.json`` and the files its distribution lists (``contentUrl``)."""
    if not (out_dir / "croissant.json").is_file() or not (out_dir / "README.md").is_file():
        return "no croissant.json and README.md (not an earlier export)"
    try:
        doc = json.loads((out_dir / "croissant.json").read_text(encoding="utf-8"))
        listed = {
            str(d["contentUrl"])
            for d in doc.get("distribution", [])
            if isinstance(d, dict) and d.get("@type") == "cr:FileObject"
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "croissant.json that cannot be read (not an earlier export)"
    ours = {"README.md", "croissant.json", *listed}
    folders = {str(p) for f in listed for p in Path(f).parents if str(p) != "."}
    for entry in sorted(out_dir.rglob("*")):
        rel = str(entry.relative_to(out_dir))
        if entry.is_dir() and not entry.is_symlink():
            if rel not in folders:
                return rel
        elif rel not in ours:
            return rel
    return None


def _nonempty(directory: Path) -> bool:
    try:
        return any(directory.iterdir())
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise WorkspaceError(f"cannot read: {exc.strerror or exc}", path=directory) from exc


def _remove_dead_temp_dirs(out_dir: Path) -> None:
    """Remove the hidden directories that exports to ``out_dir`` on this host left when they
    were killed (their process is gone); those of live runs are left alone."""
    parent = out_dir.parent
    if not parent.is_dir():
        return
    host = host_name()
    for entry in parent.iterdir():
        m = _TEMP_DIR.match(entry.name)
        if m is None or m["name"] != out_dir.name or m["host"] != host:
            continue
        try:
            os.kill(int(m["pid"]), 0)
            continue  # a live run's
        except ProcessLookupError:
            pass
        except PermissionError:
            continue  # someone else's live process
        _log.warning("removing %s, left by an interrupted export", entry)
        shutil.rmtree(entry, ignore_errors=True)


def _publish(tmp: Path, out_dir: Path) -> None:
    """Put the finished export ``tmp`` at ``out_dir`` (absent, empty, or an earlier export
    checked by :func:`_check_destination`)."""
    try:
        if not _nonempty(out_dir):
            # rename(2) replaces an empty directory in one step.
            os.rename(tmp, out_dir)
        elif exchange_paths(tmp, out_dir):
            # ``tmp`` is now the earlier export. The new one is published whatever happens
            # here: what cannot be removed now, the next export removes (its process gone).
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            old = temp_path_beside(out_dir, "export")
            os.rename(out_dir, old)
            try:
                os.rename(tmp, out_dir)
            except BaseException:
                os.rename(old, out_dir)
                raise
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        raise WorkspaceError(f"cannot publish the export: {exc.strerror or exc}", out_dir) from exc
    fsync_dir(out_dir.parent)


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
    #: sha256 of the workspace's tables, keyed ``tables/<name>.parquet``.
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
                "tables_sha256": self.tables[f"tables/{config_name}.parquet"],
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
    keys = _event_keys(events, log_ids)
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
# The dataset card and the Croissant metadata
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Facts:
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
    #: sha256 of the workspace's tables, keyed ``tables/<name>.parquet``.
    tables: Mapping[str, str]
    #: The tables stage's row counts and rejects, as recorded.
    tables_counts: Mapping[str, int]
    tables_rejects: Mapping[str, int]
    #: When the tables were made (their record's ``finished_utc``, ISO 8601), "" if unknown.
    tables_finished_utc: str = ""

    def counts(self) -> dict[str, SplitCounts]:
        """Events, rough events and point rows per split."""
        return {
            split: SplitCounts(
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


def _columns(scores: Scores | None) -> dict[str, tuple[ColumnSpec, ...]]:
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


def _q(text: str) -> str:
    """A YAML scalar: JSON's double-quoted string is valid YAML."""
    return json.dumps(text, ensure_ascii=False)


def _size_category(rows: int) -> str:
    """The Hub's size category of a dataset of ``rows`` rows (its largest config)."""
    bounds = [
        (1_000, "n<1K"),
        (10_000, "1K<n<10K"),
        (100_000, "10K<n<100K"),
        (1_000_000, "100K<n<1M"),
        (10_000_000, "1M<n<10M"),
        (100_000_000, "10M<n<100M"),
        (1_000_000_000, "100M<n<1B"),
    ]
    return next((name for bound, name in bounds if rows < bound), "n>1B")


def _yaml_header(facts: _Facts) -> list[str]:
    """The card's metadata: license, names, configs -> files, features and split sizes."""
    simulated = any(s.sim is not None for s in facts.sources)
    tags = [
        "robotics",
        "autonomous-driving",
        "off-road",
        "terrain-roughness",
        "lidar",
        "point-cloud",
        "imu",
        "self-supervised",
        *(["simulated", "synthetic"] if simulated else []),
    ]
    largest = max(facts.rows(name, split) for name in facts.columns for split in SPLITS)
    lines = [
        "---",
        f"license: {LICENSE}",
        f"pretty_name: {_q(PRETTY_NAME)}",
        "task_categories:",
        "- tabular-classification",
        "tags:",
        *(f"- {t}" for t in tags),
        "size_categories:",
        f"- {_q(_size_category(largest))}",
        "configs:",
    ]
    for name in facts.columns:
        lines.append(f"- config_name: {name}")
        if name == EVENTS:
            lines.append("  default: true")
        lines.append("  data_files:")
        for split in SPLITS:
            lines += [f"  - split: {split}", f"    path: {_q(data_file(name, split))}"]
    lines.append("dataset_info:")
    for name, columns in facts.columns.items():
        lines += [f"- config_name: {name}", "  features:"]
        for col in columns:
            lines += [f"  - name: {col.name}", f"    dtype: {TYPES[col.type][0]}"]
        lines.append("  splits:")
        for split in SPLITS:
            lines += [
                f"  - name: {split}",
                f"    num_bytes: {facts.arrow_bytes[data_file(name, split)]}",
                f"    num_examples: {facts.rows(name, split)}",
            ]
        files = [data_file(name, split) for split in SPLITS]
        lines += [
            f"  download_size: {sum(facts.files[f][0] for f in files)}",
            f"  dataset_size: {sum(facts.arrow_bytes[f] for f in files)}",
        ]
    lines.append("---")
    return lines


def _pct(part: int, whole: int) -> str:
    return f"{100.0 * part / whole:.2f} %" if whole else "n/a"


def _num(value: float) -> str:
    """A measured value for people: 4 significant digits."""
    return f"{value:.4g}"


def _cell(text: str) -> str:
    """Text for a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def _column_table(columns: Sequence[ColumnSpec]) -> list[str]:
    lines = ["| column | type | unit | meaning |", "| --- | --- | --- | --- |"]
    for col in columns:
        values = f" (one of {', '.join(repr(v) for v in col.values)})" if col.values else ""
        lines.append(
            f"| `{col.name}` | {TYPES[col.type][0]} | {col.unit or '-'} | "
            f"{_cell(col.description + values)} |"
        )
    return lines


def _shock_definition(config: PipelineConfig) -> str:
    lc = config.label
    statistic = {
        "max_abs": "the peak (largest absolute value)",
        "rms": "the root mean square",
    }.get(lc.shock_statistic, f"the {lc.shock_statistic}")
    return (
        f"`shock_g` is {statistic} over the event of the IMU's z acceleration (in the vehicle "
        f"frame) passed through a {lc.fir_taps}-tap linear-phase FIR high-pass filter that "
        f"removes 0-{lc.fir_stop_hz:g} Hz (gain 1 within 5 % from {lc.fir_pass_hz:g} Hz up): "
        "removing 0 Hz removes gravity, the rest the suspension's oscillations (paper, sect. "
        f"5.1), in G (1 G = {lc.gravity_mps2:g} m/s^2)."
        + (
            " Each filtered impact counts for the one event whose span holds its peak time: "
            "the filter's response to an impact in a neighbouring event is left out "
            '(`label.attribution = "impact"`).'
            if lc.attribution == "impact" and lc.shock_statistic == "max_abs"
            else ""
        )
    )


def _log_rows(facts: _Facts) -> list[str]:
    """The provenance table: one row per source log."""
    lines = [
        "| log_id | source file | sha256 | bytes | origin | events train / test |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for s in facts.sources:
        n = {
            split: int(
                np.count_nonzero(
                    np.asarray(facts.events[split].column("log_id").to_pylist(), dtype=object)
                    == s.log_id
                )
            )
            for split in SPLITS
        }
        if s.sim is not None:
            what = "simulated (`terrain sim`"
            details = [f"{k} {s.sim[k]}" for k in ("profile", "seed") if k in s.sim]
            origin = what + (", " + ", ".join(details) if details else "") + ")"
        else:
            origin = "recorded"
        lines.append(
            f"| `{s.log_id}` | `{_cell(s.file_name)}` | `{s.sha256}` | {s.size_bytes} | "
            f"{origin} | {n['train']} / {n['test']} |"
        )
    return lines


def _distance_lines(facts: _Facts) -> list[str]:
    """Per log and split, the stretch of the driven path its events cover."""
    lines = []
    for s in facts.sources:
        parts = []
        for split in SPLITS:
            ev = facts.events[split]
            mine = ev.filter(pc.equal(ev.column("log_id"), s.log_id))
            if mine.num_rows:
                lo = float(pc.min(mine.column("s_start_m")).as_py())
                hi = float(pc.max(mine.column("s_end_m")).as_py())
                parts.append(f"{split} {lo:.1f}-{hi:.1f} m")
            else:
                parts.append(f"{split} none")
        lines.append(f"- `{s.log_id}`: " + ", ".join(parts))
    return lines


def _per_tyre(events: pa.Table) -> NDArray[np.int64]:
    return np.concatenate(
        [events.column("points_left").to_numpy(), events.column("points_right").to_numpy()]
    ).astype(np.int64)


def dataset_card(facts: _Facts) -> str:
    """The dataset card (``README.md``): YAML metadata, then what a reader must know."""
    cfg = facts.config
    counts = facts.counts()
    total = SplitCounts(
        sum(c.events for c in counts.values()),
        sum(c.rough for c in counts.values()),
        sum(c.points for c in counts.values()),
    )
    sims = [s for s in facts.sources if s.sim is not None]
    all_events = pa.concat_tables([facts.events[s] for s in SPLITS])
    lines = _yaml_header(facts)
    lines += [
        "",
        f"# {PRETTY_NAME}",
        "",
        "Terrain *events* (consecutive stretches of a vehicle's driven path) labelled "
        "*rough* or not from the shock the vehicle's IMU felt on them, and the laser points "
        "observed on the ground under its rear tyres before it drove there: the training and "
        "test data of Stavens & Thrun (2006), *A Self-Supervised Terrain Roughness Estimator "
        "for Off-Road Autonomous Driving*. A model sees the points of an event and predicts "
        "whether it is rough; the labels come from the vehicle itself (self-supervised).",
        "",
        f"{total.events} events ({total.rough} rough) and {total.points} point rows from "
        f"{len(facts.sources)} log(s)"
        + (
            f", {len(sims)} of them simulated"
            if sims and len(sims) < len(facts.sources)
            else (": simulated data" if sims else ": recorded data")
        )
        + f". Made by the `terrain` toolkit version {__version__} (`terrain export`).",
        "",
        "## Loading",
        "",
        "Two configs, each with a `train` and a `test` split:",
        "",
        "```python",
        "from datasets import load_dataset",
        'events = load_dataset("path/to/this/folder", "events")        # DatasetDict: train, test',
        'points = load_dataset("path/to/this/folder", "event_points")',
        "```",
        "",
        "or read the Parquet files directly (`polars.read_parquet`, `pandas.read_parquet`, "
        "`pyarrow.parquet.read_table`), or through `croissant.json` (MLCommons Croissant 1.0, "
        "`mlcroissant.Dataset(jsonld=...)`, record sets `events` and `event_points`). An "
        "event's points are the `event_points` rows with its `log_id` and `event_id`; `wheel` "
        "says under which rear tyre.",
        "",
        "| config | split | file | rows | bytes | sha256 |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name in facts.columns:
        for split in SPLITS:
            path = data_file(name, split)
            size, sha = facts.files[path]
            lines.append(
                f"| {name} | {split} | `{path}` | {facts.rows(name, split)} | {size} | `{sha}` |"
            )
    lines += [
        "",
        "## Columns",
        "",
        "### `events`: one row per event",
        "",
        *_column_table(facts.columns[EVENTS]),
        "",
        "### `event_points`: one row per laser point, event and rear tyre",
        "",
        *_column_table(facts.columns[EVENT_POINTS]),
        "",
        "## The label",
        "",
        "- " + _shock_definition(cfg),
        "- `speed_mph` is the vehicle's mean speed over the event (its length over the time "
        "taken), in mph (1 mph = 0.44704 m/s).",
        "- `ruggedness` = `shock_g` / `speed_mph`, in G per mph: shock grows about linearly "
        "with speed, so the quotient is a speed-independent measure of the terrain (sect. "
        "5.2).",
        f"- `rough` = `ruggedness` >= {cfg.label.rough_threshold_g_per_mph:g} G/mph (sect. 7 "
        "uses .02 G/mph), the class to detect.",
        f"- Events are {cfg.label.event_length_m:g} m stretches of the rear axle's path "
        "(`s_start_m`, `s_end_m`: distance along it); events slower than "
        f"{cfg.label.min_speed_mps:g} m/s are not labelled.",
        f"- Here `shock_g` ranges from {_num(float(pc.min(all_events.column('shock_g')).as_py()))} "
        f"to {_num(float(pc.max(all_events.column('shock_g')).as_py()))} G, `speed_mph` from "
        f"{_num(float(pc.min(all_events.column('speed_mph')).as_py()))} to "
        f"{_num(float(pc.max(all_events.column('speed_mph')).as_py()))} mph.",
        "",
        "## Frames and units of the points",
        "",
        "- `x`, `y`, `z`: metres in a local ENU frame (x east, y north, z up) whose origin is "
        "the log's first valid GPS fix: each log has its own origin, so coordinates of "
        "different logs are not in one frame.",
        "- `tau`: the time the point was observed, in seconds on the log's clock (`t_ns`, the "
        "same time in integer nanoseconds, is exact; `tau` = `t_ns` / 1e9).",
        "- `roll_rate`, `pitch_rate`: rad/s, the time derivatives of the vehicle's estimated "
        "roll and pitch when the point was observed (the paper's gamma and psi).",
        "- `laser`: the topic of the laser that saw the point; `wheel`: `left` or `right` rear "
        "tyre.",
        f"- Which points: those within {cfg.model.wheel_window_radius_m:g} m of the ground a "
        "rear tyre traversed during the event, observed before the rear axle got there and at "
        f'most {cfg.tables.max_lookahead_s:g} s before (sect. 7: "within 30cm of terrain the '
        "vehicle's rear tires traversed\").",
    ]
    origins = [
        (s.log_id, s.header["pose"]["enu_origin"])
        for s in facts.sources
        if isinstance(s.header.get("pose", {}).get("enu_origin"), dict)
    ]
    for log_id, o in origins:
        lines.append(
            f"- ENU origin of `{log_id}`: latitude {o.get('latitude_deg')}, longitude "
            f"{o.get('longitude_deg')} (degrees, WGS84), altitude {o.get('altitude_m')} m."
        )
    scope = (
        "the logs in time order taken as one route"
        if cfg.tables.split_scope == "all_logs"
        else "each log on its own"
    )
    lines += [
        "",
        "## The split",
        "",
        f"By distance driven, as the paper trains on miles 60-70 of the race and tests on "
        f"miles 70-80: the first {100 * cfg.tables.train_fraction:g} % of the driven distance "
        f"({scope}) trains, the rest tests; an event belongs to the side its middle lies on, "
        "and its points to its split. Stretches covered:",
        "",
        *_distance_lines(facts),
        "",
        "| split | events | rough | rough share | point rows | points per tyre (median) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for split in SPLITS:
        c = counts[split]
        tyre = _per_tyre(facts.events[split])
        median = f"{float(np.median(tyre)):g}" if tyre.size else "n/a"
        lines.append(
            f"| {split} | {c.events} | {c.rough} | {_pct(c.rough, c.events)} | {c.points} | "
            f"{median} |"
        )
    if facts.scores is not None:
        mu = (
            f" (mu = {facts.scores.mu!r} in the model that was scored)"
            if facts.scores.mu is not None
            else ""
        )
        lines += [
            "",
            "## The model's scores",
            "",
            "The `events` files carry the scores of the roughness model `terrain learn` fitted "
            "on the train split: `r_combined` (eq. 5) and `predicted` = `r_combined` > mu"
            f"{mu}. On the train split they are in-sample; only the test split measures the "
            "model. They are not labels: a new model should ignore them.",
        ]
    lines += ["", "## Provenance", ""]
    lines += [
        f"Exported by the `terrain` toolkit version {__version__} from a workspace whose "
        "tables `terrain tables` wrote (sha256: "
        + ", ".join(f"`{k}` {v}" for k, v in sorted(facts.tables.items()))
        + f"), configuration `{cfg.name}` (its label, tables, model and vehicle sections "
        f"hash to {stage_config_hash(cfg)}, the `config_hash` of every Parquet file's "
        "metadata). Source logs (MCAP), by their sha256:",
        "",
        *_log_rows(facts),
    ]
    for s in sims:
        lines.append("")
        lines.append(
            f"`{s.log_id}` is simulated: its terrain, vehicle and sensors were generated by "
            "the toolkit's simulator (`terrain sim`), not recorded on a vehicle."
        )
    lines += ["", "## Known limitations", ""]
    lines += _limitations(facts, counts, total)
    lines += [
        "",
        "## Citation",
        "",
        "The method and the experiment this data reproduces:",
        "",
        "```bibtex",
        CITATION,
        "```",
        "",
        "## License",
        "",
        "Creative Commons Attribution 4.0 International (CC BY 4.0).",
        "",
    ]
    return "\n".join(lines)


def _limitations(facts: _Facts, counts: Mapping[str, SplitCounts], total: SplitCounts) -> list[str]:
    """What a user of the data must keep in mind, with this data's numbers."""
    out = []
    paper = " and ".join(f"{k} of {n:,}, {_pct(k, n)}" for k, n in PAPER_ROUGH)
    out.append(
        "- **Rare positives.** "
        + "; ".join(
            f"{split}: {c.rough} rough of {c.events} events ({_pct(c.rough, c.events)})"
            for split, c in counts.items()
        )
        + f" (the paper: {paper}). With so few positives, rates and ROC curves on the test "
        "split are uncertain: report confidence intervals."
    )
    sims = [s for s in facts.sources if s.sim is not None]
    if sims:
        accuracy = []
        for s in sims:
            acc = s.header.get("pose_accuracy", {})
            if "horizontal_rmse_m" in acc and "vertical_rmse_m" in acc:
                accuracy.append(
                    f"`{s.log_id}`: horizontal {acc['horizontal_rmse_m']} m, vertical "
                    f"{acc['vertical_rmse_m']} m RMSE"
                )
        out.append(
            f"- **Simulated data.** {len(sims)} of {len(facts.sources)} log(s) are simulated: "
            "terrain, vehicle dynamics, IMU, GPS and lasers are models, so a method that works "
            "here has not been shown to work on a real vehicle."
            + (
                " The points carry the errors of the estimated pose against the simulator's "
                "truth (" + "; ".join(accuracy) + ")."
                if accuracy
                else ""
            )
        )
    train = counts["train"]
    paper_tyre = PAPER_TRAIN_POINTS / PAPER_TRAIN_EVENTS / 2
    tyre = _per_tyre(pa.concat_tables([facts.events[s] for s in SPLITS]))
    mean_tyre = float(tyre.mean()) if tyre.size else 0.0
    out.append(
        f"- **Points per tyre far denser than the paper's.** {_num(mean_tyre)} point rows per "
        f"tyre and event on average here, against {_num(paper_tyre)} in the paper's training "
        f"set ({PAPER_TRAIN_POINTS:,} points for {PAPER_TRAIN_EVENTS:,} events): about "
        f"{_num(mean_tyre / paper_tyre)} times as many, from the lasers' rates and mounting "
        "and the event length. A model tuned here may need re-tuning (e.g. a cap on points "
        f"per tyre) at the paper's density. Train split: {train.points} point rows for "
        f"{train.events} events."
    )
    distinct = facts.tables_counts.get("distinct_points")
    if distinct:
        out.append(
            "- **Rows are not distinct points.** A point near the boundary of two events is "
            f"listed under each: the tables stage counted {distinct} distinct points under the "
            "tyres (before leaving out the events it could not score) for these "
            f"{total.points} point rows."
        )
    dropped = int(facts.tables_rejects.get("too_few_points", 0))
    label_rejects: dict[str, int] = {}
    for s in facts.sources:
        for reason, n in (s.header.get("label", {}).get("rejects", {}) or {}).items():
            label_rejects[str(reason)] = label_rejects.get(str(reason), 0) + int(n)
    parts = []
    if dropped:
        parts.append(
            f"{dropped} event(s) had fewer than {facts.config.tables.min_points_per_wheel} "
            "points under a tyre and were left out (they cannot be scored)"
        )
    if any(label_rejects.values()):
        parts.append(
            "stretches not labelled at all: "
            + ", ".join(f"{n} {reason}" for reason, n in sorted(label_rejects.items()) if n)
        )
    if parts:
        out.append(
            "- **Not every stretch is an event.** " + "; ".join(parts) + ". The events are "
            "the driven path minus these, which is not a random sample of it."
        )
    length = sum(
        float(pc.sum(pc.subtract(e.column("s_end_m"), e.column("s_start_m"))).as_py() or 0.0)
        for e in facts.events.values()
    )
    out.append(
        f"- **Small.** The events cover {length:.0f} m of driving; the paper's splits are 10 "
        "miles (16.1 km) each."
    )
    out.append(
        "- **Labels from the vehicle's own sensors.** Shock depends on the vehicle and its "
        "suspension, and dividing by speed is a linear approximation (the paper's Fig. 5); "
        "an event is rough for this vehicle at the speed it drove."
    )
    out.append(
        "- **Each log has its own frame.** Compare coordinates only within a log (the same "
        "`log_id`)."
    )
    return out


def croissant_metadata(facts: _Facts) -> dict[str, Any]:
    """The Croissant 1.0 description of the export (JSON-LD): every file with its sha256,
    a file set per config, and a record set per config whose fields are its columns."""
    counts = facts.counts()
    sims = [s for s in facts.sources if s.sim is not None]
    kind = "simulated" if len(sims) == len(facts.sources) else "recorded" if not sims else "mixed"
    description = (
        "Terrain events labelled rough or not from the shock a vehicle's IMU felt on them "
        "(ruggedness = shock in G / speed in mph >= "
        f"{facts.config.label.rough_threshold_g_per_mph:g} G/mph), and the laser points "
        "observed under its rear tyres before it drove there: the data of Stavens & Thrun "
        "(2006), reproduced by the terrain toolkit "
        f"{__version__} from {len(facts.sources)} {kind} log(s). "
        + "; ".join(
            f"{split}: {c.events} events, {c.rough} rough, {c.points} point rows"
            for split, c in counts.items()
        )
        + ". See README.md."
    )
    distribution: list[dict[str, Any]] = []
    for name in facts.columns:
        for split in SPLITS:
            path = data_file(name, split)
            size, sha = facts.files[path]
            distribution.append(
                {
                    "@type": "cr:FileObject",
                    "@id": path,
                    "name": path,
                    "description": f"the {split} split of the {name} config",
                    "contentUrl": path,
                    "contentSize": f"{size} B",
                    "encodingFormat": "application/x-parquet",
                    "sha256": sha,
                }
            )
    for name in facts.columns:
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": f"{name}-files",
                "name": f"{name}-files",
                "description": f"the {name} config's Parquet files, one per split",
                "encodingFormat": "application/x-parquet",
                "includes": f"data/{name}/*.parquet",
            }
        )
    record_sets = []
    for name, columns in facts.columns.items():
        fields: list[dict[str, Any]] = [
            {
                "@type": "cr:Field",
                "@id": f"{name}/{col.name}",
                "name": col.name,
                "description": col.description + (f" [{col.unit}]" if col.unit else ""),
                "dataType": TYPES[col.type][1],
                "source": {"fileSet": {"@id": f"{name}-files"}, "extract": {"column": col.name}},
            }
            for col in columns
        ]
        if name == EVENT_POINTS:
            # A point's split is the file it is in (its event's split).
            fields.append(
                {
                    "@type": "cr:Field",
                    "@id": f"{name}/split",
                    "name": "split",
                    "description": "'train' or 'test': the split of the point's event (its file)",
                    "dataType": "sc:Text",
                    "source": {
                        "fileSet": {"@id": f"{name}-files"},
                        "extract": {"fileProperty": "fullpath"},
                        "transform": {
                            "regex": f"^data/{name}/(train|test)-[0-9]+-of-[0-9]+\\.parquet$"
                        },
                    },
                }
            )
        record_sets.append(
            {
                "@type": "cr:RecordSet",
                "@id": name,
                "name": name,
                "description": (
                    "one row per event: its shock, speed, ruggedness, rough label and split"
                    if name == EVENTS
                    else "one row per laser point, event and rear tyre (the paper's L_i)"
                ),
                "field": fields,
            }
        )
    return {
        "@context": CROISSANT_CONTEXT,
        "@type": "sc:Dataset",
        "name": DATASET_NAME,
        "description": description,
        "conformsTo": CROISSANT_CONFORMS_TO,
        "citeAs": CITATION,
        "license": "https://creativecommons.org/licenses/by/4.0/",
        # Where the dataset is published is not known here: its landing page is the card
        # beside this file (replace with the hosting URL when publishing).
        "url": "README.md",
        "version": __version__,
        # The day the tables were made: the data's date, so exporting the same tables
        # again gives the same file (mlcroissant warns without a datePublished).
        **({"datePublished": facts.tables_finished_utc[:10]} if facts.tables_finished_utc else {}),
        "keywords": [
            "terrain roughness",
            "self-supervised learning",
            "lidar",
            "off-road driving",
            *(["simulated"] if sims else []),
        ],
        "distribution": distribution,
        "recordSet": record_sets,
    }


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def _fsync_tree(directory: Path) -> None:
    """fsync every directory of the export (its files were fsynced by their writers), so
    the rename that publishes it cannot survive a power cut without its contents."""
    for root, _dirs, _files in os.walk(directory):
        fsync_dir(Path(root))


def run_export(
    workspace: Workspace, out_dir: Path, config: PipelineConfig, *, overwrite: bool = False
) -> ExportResult:
    """Write the dataset of the workspace's tables to ``out_dir`` (module docstring)."""
    start = time.perf_counter()
    out_dir = Path(os.path.abspath(out_dir))
    _check_destination(workspace, out_dir, overwrite)
    tables = table_inputs(workspace, config)
    record = workspace.manifest().stage(tables_stage.STAGE)
    assert record is not None  # _tables_inputs refuses a missing record
    events = _read_events(workspace)
    log_ids = tuple(dict.fromkeys(events.column("log_id").to_pylist()))
    # Each log's labelling configuration first: a threshold changed since is the likelier
    # cause of labels that disagree with it, and the more useful message.
    sources = tuple(_log_source(workspace, log_id, config) for log_id in log_ids)
    _check_labels(events, config, workspace.events_table)
    scores, warnings = _model_scores(workspace, tables, events)
    provenance = _Provenance(tuple(s.sha256 for s in sources), stage_config_hash(config), tables)
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WorkspaceError(f"cannot create: {exc.strerror or exc}", out_dir.parent) from exc
    _remove_dead_temp_dirs(out_dir)
    tmp = temp_path_beside(out_dir, "export")
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise WorkspaceError(f"cannot create: {exc.strerror or exc}", tmp) from exc
        by_split = _write_events(tmp, events, scores, provenance)
        written = _write_points(tmp, workspace, events, log_ids, provenance)
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
        facts = _Facts(
            config=config,
            sources=sources,
            events=by_split,
            points=points,
            files=files,
            arrow_bytes=in_memory,
            columns=_columns(scores),
            scores=scores,
            tables=tables,
            tables_counts=dict(record.row_counts),
            tables_rejects=dict(record.rejects),
            tables_finished_utc=record.finished_utc,
        )
        atomic_write_text(tmp / "README.md", dataset_card(facts))
        atomic_write_text(
            tmp / "croissant.json",
            json.dumps(croissant_metadata(facts), indent=2, ensure_ascii=False, allow_nan=False)
            + "\n",
        )
        _fsync_tree(tmp)
        _publish(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for warning in warnings:
        _log.warning("%s", warning)
    return ExportResult(
        out_dir=out_dir,
        splits=facts.counts(),
        logs=log_ids,
        scores=scores is not None,
        files=tuple(sorted([*files, "README.md", "croissant.json"])),
        seconds=time.perf_counter() - start,
        warnings=tuple(warnings),
    )


__all__ = [
    "STAGE",
    "ExportResult",
    "SplitCounts",
    "croissant_metadata",
    "data_file",
    "dataset_card",
    "run_export",
]

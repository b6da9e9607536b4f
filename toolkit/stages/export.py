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
(Linux ``renameat2``; elsewhere two renames, with a moment when ``OUT`` is absent). The same
workspace gives the same bytes: no file holds a time other than the data's.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import logging
import os
import re
import shutil
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit import __version__
from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import StageError, WorkspaceError
from toolkit.generations import fsync_dir, host_name
from toolkit.stages import label as label_stage
from toolkit.stages import tables as tables_stage
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
    atomic_write_text,
    file_sha256,
    require_finished,
    temp_path_beside,
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
#: The columns of a point row, in order (the ``event_points`` schema's).
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
#: Croissant 1.0's JSON-LD context, as the specification gives it.
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
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}
CROISSANT_CONFORMS_TO = "http://mlcommons.org/croissant/1.0"
#: Linux renameat2(2): relative to the working directory; swap the two names.
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
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


def _tables_inputs(workspace: Workspace, config: PipelineConfig) -> dict[str, str]:
    """sha256 of the two tables (keyed as the consumers of the tables key them), refused
    unless they are what the last finished ``terrain tables`` wrote, with this
    configuration."""
    paths = (workspace.events_table, workspace.event_points_table)
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise StageError("no training tables; run `terrain tables` first", path=missing[0])
    hashes = {p.name: file_sha256(p) for p in paths}
    record = workspace.manifest().stage(tables_stage.STAGE)
    require_finished(record, tables_stage.STAGE, hashes, workspace.tables_dir)
    # The card states the split's fraction from the configuration: it must be the one the
    # tables were split with.
    if record is not None and record.config_hash != tables_stage.stage_config_hash(config):
        raise StageError(
            "the tables were made with another configuration than the workspace's; run "
            "`terrain tables` again",
            path=workspace.manifest_path,
        )
    return {f"tables/{name}": sha for name, sha in hashes.items()}


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
        if isinstance(meta, dict) and isinstance(meta.get("terrain_sim"), dict):
            sim = meta["terrain_sim"]
    header = {k: doc[k] for k in ("label", "pose", "pose_accuracy") if isinstance(doc.get(k), dict)}
    return LogSource(
        log_id=log_id,
        file_name=Path(str(source.get("path", ""))).name or "(unknown)",
        sha256=str(source["sha256"]),
        size_bytes=int(source.get("size_bytes", 0)),
        sim=sim,
        header=header,
    )


def _read_events(workspace: Workspace, config: PipelineConfig) -> pa.Table:
    """The tables' events, the schema's columns in its order; refused when a label is not
    what the card will say it is."""
    schema = load_table_schema("tables_events")
    events = read_table(workspace.events_table, "tables_events", columns=schema.column_names)
    if events.num_rows == 0:
        raise StageError(
            "the tables hold no event: nothing to export (see `terrain label`)",
            path=workspace.events_table,
        )
    # The card defines rough as ruggedness >= the threshold: check the rows agree, so a
    # table labelled by other rules cannot go out under this definition.
    ruggedness = events.column("ruggedness").to_numpy()
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    expected = ruggedness >= config.label.rough_threshold_g_per_mph
    disagree = int(np.count_nonzero(rough != expected))
    if disagree:
        raise StageError(
            f"{disagree} event(s) whose rough label is not ruggedness >= "
            f"{config.label.rough_threshold_g_per_mph:g} G/mph; run `terrain label` and "
            "`terrain tables` again",
            path=workspace.events_table,
        )
    return events


def _event_keys(events: pa.Table, log_ids: Sequence[str]) -> NDArray[np.int64]:
    """One int64 per event: ``log index * (largest event id + 1) + event_id``."""
    code = {log_id: i for i, log_id in enumerate(log_ids)}
    logs = np.array([code[v] for v in events.column("log_id").to_pylist()], dtype=np.int64)
    ids = events.column("event_id").to_numpy().astype(np.int64)
    return logs * (int(ids.max()) + 1) + ids


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
    if model_sha and workspace.model_path.is_file():
        if file_sha256(workspace.model_path) == model_sha:
            mu = float(_read_json(workspace.model_path)["mu"])
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
    root = Path(os.path.abspath(workspace.root))
    if out_dir == root or out_dir in root.parents:
        # Replacing it would delete the workspace the export is made from.
        raise StageError(f"holds the workspace {workspace.root}; export elsewhere", path=out_dir)
    if not _nonempty(out_dir):
        return
    if not overwrite:
        raise StageError(
            "exists and is not empty; choose a new directory or use --overwrite to replace "
            "the export there",
            path=out_dir,
        )
    # --overwrite replaces an earlier export, never an arbitrary folder of someone's files.
    if not (out_dir / "croissant.json").is_file() or not (out_dir / "README.md").is_file():
        raise StageError(
            "is not an earlier export (no croissant.json and README.md); refusing to "
            "replace it, choose a new or empty directory",
            path=out_dir,
        )


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


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``);
    False where the system or file system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _publish(tmp: Path, out_dir: Path) -> None:
    """Put the finished export ``tmp`` at ``out_dir`` (absent, empty, or an earlier export
    checked by :func:`_check_destination`)."""
    try:
        if not _nonempty(out_dir):
            # rename(2) replaces an empty directory in one step.
            os.rename(tmp, out_dir)
        elif _exchange(tmp, out_dir):
            shutil.rmtree(tmp)  # now the earlier export
        else:
            old = temp_path_beside(out_dir, "export")
            os.rename(out_dir, old)
            try:
                os.rename(tmp, out_dir)
            except BaseException:
                os.rename(old, out_dir)
                raise
            shutil.rmtree(old)
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
) -> dict[str, int]:
    """The event points, streamed into one file per split (the split of each row's event),
    in the tables' order; returns the rows per split."""
    keys = _event_keys(events, log_ids)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    is_train = np.asarray(events.column("split").to_pylist(), dtype=object) == "train"
    train_sorted = is_train[order]
    code = {log_id: i for i, log_id in enumerate(log_ids)}
    width = int(events.column("event_id").to_numpy().max()) + 1
    path = workspace.event_points_table
    writers = {split: provenance.writer(tmp, EVENT_POINTS, split, "event_points") for split in SPLITS}
    rows = dict.fromkeys(SPLITS, 0)
    try:
        for batch in iter_table_batches(
            path,
            "event_points",
            columns=POINT_COLUMNS,
            batch_rows=POINT_BATCH,
            as_dictionary=DICTIONARY_COLUMNS,
        ):
            table = pa.Table.from_batches([batch])
            logs = batch.column("log_id")
            # The dictionary's few values looked up once, then spread by their indices.
            values = np.array(
                [code.get(v, -1) for v in logs.dictionary.to_pylist()], dtype=np.int64
            )
            log_code = values[logs.indices.to_numpy(zero_copy_only=False)]
            event_id = batch.column("event_id").to_numpy().astype(np.int64)
            key = log_code * width + event_id
            at = np.minimum(np.searchsorted(sorted_keys, key), sorted_keys.size - 1)
            known = (log_code >= 0) & (event_id < width) & (sorted_keys[at] == key)
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
        for writer in writers.values():
            writer.finish()
        for writer in writers.values():
            writer.publish()
    except BaseException:
        for writer in writers.values():
            writer.abort()
        raise
    return rows

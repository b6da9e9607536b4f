"""Ingest: one MCAP log -> the contract's per-sensor Parquet tables and the log's manifest.

The log is streamed chunk by chunk, each chunk's messages of a topic decoded in one vectorised
call, converted by the topic's role and screened (:mod:`toolkit.ingestion`), so memory stays
bounded by a chunk plus a small reorder buffer per table, whatever the log's length. Every
message read is written or rejected for one reason (``read = written + sum(rejects)``), and
nothing is published until every table is complete. ``docs/ingest.md`` lists the reject
reasons, the counts, the outputs and the manifest's sections.

This module is the stage: the log's identity (:func:`_locate`), its steps in order
(:func:`_compute`) and its record (:func:`_recall`).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from toolkit.config import ImuConfig, LidarConfig, PipelineConfig, TimeConfig, TopicsConfig
from toolkit.errors import LogReadError
from toolkit.ingestion.accounts import lost_by_topic, reject_totals, rejects_by_topic
from toolkit.ingestion.plans import resolve_topics
from toolkit.ingestion.reorder import DEFAULT_REORDER_BUFFER_BYTES
from toolkit.ingestion.run import MCAP_METADATA_OUTPUT, IngestRun, make_buffers
from toolkit.manifest import StageRecord, file_sha256
from toolkit.mcapio.reader import LogReader, ReadReport
from toolkit.progress import progress
from toolkit.sim.record import sim_origin
from toolkit.stages.contract import Call, Made, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.stages.truth import truth_to_pose_frame
from toolkit.workspace import Workspace, make_log_id

_log = logging.getLogger(__name__)

#: The manifest's name for this stage.
STAGE = "ingest"


@dataclass(frozen=True)
class IngestResult:
    """What :func:`ingest_log` did to one log.

    ``status`` is ``"ingested"`` or ``"up_to_date"`` (nothing rewritten). ``row_counts`` is
    rows per output table; ``rejects`` and ``lost`` are counts by topic, then reason
    (``lost``: messages the reader could not salvage from a damaged file).
    """

    log_path: Path
    log_id: str
    status: str
    row_counts: dict[str, int]
    rejects: dict[str, dict[str, int]]
    lost: dict[str, dict[str, int]]
    warnings: tuple[str, ...]
    seconds: float

    def summary(self) -> str:
        """One line for people."""
        rows = ", ".join(f"{k} {v}" for k, v in sorted(self.row_counts.items()))
        rejected = sum(sum(r.values()) for r in self.rejects.values())
        lost = sum(sum(r.values()) for r in self.lost.values())
        return (
            f"{self.log_path}: {self.status.replace('_', ' ')} as {self.log_id} "
            f"({rows}; {rejected} rejected, {lost} lost) in {self.seconds:.2f} s"
        )


@dataclass(frozen=True)
class IngestSettings:
    """What ingest reads of the configuration: the topics of each role, the clocks and how a
    3-D lidar's clouds are read (its
    up-to-date key: a pose tuning change must not make every ingest stale); and how many bytes
    each table holds back for sorting (not a configuration key)."""

    topics: TopicsConfig
    time: TimeConfig
    lidar: LidarConfig
    imu: ImuConfig
    buffer_bytes: int = DEFAULT_REORDER_BUFFER_BYTES


def ingest_log(
    log_path: Path,
    workspace: Workspace,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    reorder_buffer_bytes: int = DEFAULT_REORDER_BUFFER_BYTES,
) -> IngestResult:
    """Ingest one MCAP log into ``WS/logs/<log_id>/`` (``docs/ingest.md``).

    Idempotent: when the manifest records an ingest of the same log content (sha256) under
    the same configuration and its outputs exist, nothing is rewritten and the status is
    ``"up_to_date"``; ``overwrite=True`` redoes it. Refuses (ConfigError) a configuration other
    than the workspace's unless ``overwrite``, and records it as ``WS/config.toml`` only once
    it has succeeded (a failed first ingest leaves no configuration behind).
    Raises StageError when none of the configured topics is in the log or nothing usable is,
    LogReadError when the file cannot be read at all. ``reorder_buffer_bytes`` bounds the
    rows each table holds back for sorting.
    """
    settings = IngestSettings(
        config.topics, config.time, config.lidar, config.imu, reorder_buffer_bytes
    )
    return run_stage(
        SPEC, workspace, config, overwrite=overwrite, settings=settings, source=Path(log_path)
    )


# --------------------------------------------------------------------------------------
# The log's identity and an up-to-date ingest's outcome
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Source:
    """The log file being ingested: its path, sha256 and identity when hashed."""

    path: Path
    sha256: str
    identity: tuple[int, int, int, int]


def _identity(path: Path) -> tuple[int, int, int, int]:
    """(device, inode, size, mtime ns): what changes when a file is rewritten or appended."""
    st = path.stat()
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _locate(log_path: Path) -> tuple[str, dict[str, str], _Source]:
    """The log's id and its file's hash (ingest's one input); LogReadError when it is no
    regular file."""
    if not log_path.exists():
        raise LogReadError("no such log file", path=log_path)
    if not log_path.is_file():  # a directory, a FIFO, a device: never opened, never hashed
        raise LogReadError("not a regular file (a log is an MCAP file)", path=log_path)
    before = _identity(log_path)
    sha256 = file_sha256(log_path)
    return make_log_id(log_path.stem, sha256), {"log": sha256}, _Source(log_path, sha256, before)


def _recall(last: Recalled[IngestSettings]) -> IngestResult:
    """The outcome of an up-to-date ingest, from its record."""
    source: _Source = last.found
    _log.info("%s: up to date (%s)", source.path, last.log_id)
    detail = last.header.get(STAGE, {})
    topics = detail.get("topics", {}) if isinstance(detail, Mapping) else {}
    return IngestResult(
        log_path=source.path,
        log_id=last.log_id,
        status="up_to_date",
        row_counts=dict(last.record.row_counts),
        rejects=_nonzero(topics, "rejects"),
        lost=_nonzero(topics, "lost"),
        warnings=(),
        seconds=last.seconds,
    )


def _nonzero(topics: Mapping[str, Any], key: str) -> dict[str, dict[str, int]]:
    """topic -> reason -> count from the manifest's per-topic detail, zeros left out."""
    out: dict[str, dict[str, int]] = {}
    for topic, acc in topics.items():
        counts = {str(k): int(v) for k, v in dict(acc.get(key, {})).items() if v}
        if counts:
            out[topic] = counts
    return out


# --------------------------------------------------------------------------------------
# The steps
# --------------------------------------------------------------------------------------


def _compute(call: Call[IngestSettings]) -> Made[IngestResult]:
    """Read the log into its tables (``docs/ingest.md``); the runner records them."""
    source: _Source = call.found
    previous = call.manifest.stage(STAGE)
    run, report, missing, warnings = _read(call.settings, source, call)
    try:
        if _identity(source.path) != source.identity:  # the hash must describe the bytes read
            raise LogReadError(
                "the log changed while it was read (size or modification time); ingest "
                "it again once it is complete",
                path=source.path,
            )
        warnings += _finish(run, report)  # the runner says them on the terminal, once
        out_files = run.commit(call.files.dir)
    except BaseException:
        run.discard()
        raise
    _remove_stale_outputs(call.files.dir, previous, out_files)
    run.timings["total"] = time.perf_counter() - call.start
    return _made(call, source, run, report, missing, out_files, warnings)


def _read(
    settings: IngestSettings, source: _Source, call: Call[IngestSettings]
) -> tuple[IngestRun, ReadReport, dict[str, list[str]], list[str]]:
    """Plan the log's configured topics and read every batch into a run's tables (aside);
    the run, the reader's report, the missing topics by role and the warnings so far. The
    run's partial files are removed if reading fails."""
    run: IngestRun | None = None
    try:
        with LogReader(source.path, topics=_configured_topics(settings)) as reader:
            plans, missing, warnings = resolve_topics(
                settings.topics, settings.time, reader.channels(), source.path, settings.lidar
            )
            buffers = make_buffers(
                plans,
                call.files.dir,
                source_sha256=source.sha256,
                config_hash=call.config_hash,
                buffer_bytes=settings.buffer_bytes,
            )
            run = IngestRun(
                plans,
                buffers,
                settings.topics,
                settings.time,
                source.path,
                settings.lidar,
                settings.imu,
            )
            t_read = time.perf_counter()
            for batch in progress(
                reader.batches(), desc=f"ingest {source.path.name}", unit="batch"
            ):
                run.consume(batch)
            spent = run.timings["decode_convert"] + run.timings["write"]
            run.timings["read"] = time.perf_counter() - t_read - spent
            report = reader.report
    except BaseException:
        if run is not None:
            run.discard()
        raise
    return run, report, missing, warnings


def _finish(run: IngestRun, report: ReadReport) -> list[str]:
    """Complete the run's tables (the truth moved into the pose's frame); its warnings and
    the reader's damage line."""
    run.mcap_metadata = report.metadata
    run.finish(report)
    if "truth_pose" in run.outputs:
        t0 = time.perf_counter()
        _truth_to_pose_frame(run)
        run.timings["finish"] += time.perf_counter() - t0
    warnings = list(run.warnings)
    damage_warning = report.summary_line()  # the same line `terrain info` prints
    if damage_warning:
        warnings.append(damage_warning)
    return warnings


def _truth_to_pose_frame(run: IngestRun) -> None:
    """Rewrite the finished truth table in the pose's frame (see stages/truth.py)."""
    sim = sim_origin(run.mcap_metadata)
    if sim is None:
        run.warnings.append("truth_pose left in the simulator's frame: no terrain_sim origin")
        return
    moved = truth_to_pose_frame(run.writers["truth_pose"], run.writers["gps"].finished_path, sim)
    if isinstance(moved, str):
        run.warnings.append(moved)
    else:
        run.writers["truth_pose"] = moved


def _made(
    call: Call[IngestSettings],
    source: _Source,
    run: IngestRun,
    report: ReadReport,
    missing: Mapping[str, list[str]],
    out_files: Sequence[str],
    warnings: Sequence[str],
) -> Made[IngestResult]:
    """The outcome and what the runner records: rows, rejects, timings, the manifest's
    ``source`` and ``ingest`` sections."""
    source_header = {
        "path": str(source.path.resolve()),
        "sha256": source.sha256,
        "log_id": call.log_id,
        "size_bytes": source.path.stat().st_size,
    }
    result = IngestResult(
        log_path=source.path,
        log_id=call.log_id,
        status="ingested",
        row_counts=run.row_counts(),
        rejects=rejects_by_topic(run.accounts),
        lost=lost_by_topic(run.accounts),
        warnings=tuple(warnings),
        seconds=time.perf_counter() - call.start,
    )
    _log.info("%s", result.summary())
    return Made(
        result,
        tuple(out_files),
        row_counts=run.row_counts(),
        rejects=reject_totals(run.accounts),
        timings_s=run.timings,
        warnings=tuple(warnings),
        header={"source": source_header, "ingest": run.detail(report, missing)},
    )


def _configured_topics(config: IngestSettings) -> list[str]:
    return [t for topics in config.topics.by_role().values() for t in topics]


def _remove_stale_outputs(log_dir: Path, old: StageRecord | None, current: Sequence[str]) -> None:
    """Remove outputs a previous ingest wrote that this one did not (e.g. a role dropped)."""
    if old is None:
        return
    for name in set(old.outputs) - set(current):
        if "/" in name or name.startswith("."):
            continue
        with contextlib.suppress(FileNotFoundError):
            (log_dir / name).unlink()


SPEC = Stage(
    STAGE,
    "log",
    makes=("imu", "gps", "heading", "wheels", "laser", "tf_static", "mcap_metadata"),
    settings=IngestSettings,
    locate=_locate,
    compute=_compute,
    recall=_recall,
    rows=None,
    unit="log",
)


__all__ = [
    "SPEC",
    "STAGE",
    "IngestResult",
    "IngestSettings",
    "MCAP_METADATA_OUTPUT",
    "ingest_log",
]

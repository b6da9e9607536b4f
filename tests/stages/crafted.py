"""For tests that craft a stage's inputs by editing an ingested workspace.

Pose refuses inputs that are not what the last finished ingest wrote (so a table an
interrupted run left, or one edited by hand, is never used). A test that edits a log's files
on purpose stands in for ingest: :func:`adopt_edits` records the files as they are now as the
ingest's outputs, as a real ingest of such a log would have, and :func:`write_table` is
tableio's, followed by that.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pyarrow as pa

from toolkit import tableio
from toolkit.manifest import Manifest, StageRecord, digest_files


def adopt_edits(log_dir: Path) -> None:
    """Record a log's current ingest outputs (sizes and sha256) in its ingest record."""
    manifest = Manifest(log_dir / "manifest.json")
    record = manifest.stage("ingest")
    assert record is not None, "the workspace has no finished ingest of this log"
    outputs = [name for name in record.outputs if (log_dir / name).exists()]
    manifest.record_stage(
        "ingest",
        dataclasses.replace(
            record, outputs=tuple(outputs), output_files=digest_files(log_dir, outputs)
        ),
    )


def write_table(path: str | Path, table: pa.Table, schema_name: str, **kwargs: Any) -> None:
    """tableio.write_table into a log's folder, then :func:`adopt_edits` of that log."""
    tableio.write_table(path, table, schema_name, **kwargs)
    adopt_edits(Path(path).parent)


def record_stage_outputs(
    log_dir: Path, stage: str, outputs: list[str], inputs: dict[str, str] | None = None
) -> None:
    """Record ``outputs`` (as they are now) as what a finished ``stage`` wrote in this log
    from ``inputs`` (name -> sha256), as a real run of that stage with the default
    configuration and this code would have: for tests that craft a stage's outputs by hand."""
    manifest = Manifest(log_dir / "manifest.json")
    manifest.record_stage(stage, crafted_record(stage, outputs, log_dir, inputs))


def crafted_record(
    stage: str, outputs: list[str], log_dir: Path, inputs: dict[str, str] | None = None
) -> StageRecord:
    """The record a run of ``stage`` with the default configuration and this code leaves
    for ``outputs`` of ``log_dir`` as they are now, made from ``inputs``."""
    from toolkit.config import default_config
    from toolkit.stages.registry import stage as registered
    from toolkit.stages.runner import code_version_for

    spec = registered(stage)
    return StageRecord(
        inputs=dict(inputs or {}),
        config_hash=spec.config_hash(default_config()),
        outputs=tuple(outputs),
        output_files=digest_files(log_dir, outputs),
        code_version=code_version_for(spec),
        config_sections=spec.hashed_sections(default_config()),
    )

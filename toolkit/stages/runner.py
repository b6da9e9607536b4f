"""The runner: what every stage needs done around its computation, done once.

For a stage on the runner's check (:attr:`Stage.compute`), :func:`run_stage`

1. opens a new generation of the log (a per-log stage), committed in one atomic switch only
   when the stage computed something: killed at any moment, the log is as before or after;
2. hashes the files the stage needs (:attr:`Stage.needs`), refusing one missing, or one its
   maker's last finished run did not write (changed, partial, left by an interrupted run);
3. hashes the configuration the stage reads and, unless ``overwrite``, compares both with
   the stage's last record and its outputs as written: when nothing changed it returns the
   stage's recalled outcome (``up_to_date``) without work;
4. otherwise calls the stage's compute function with its own frozen settings, and records
   what it read and wrote in the manifest (:class:`~toolkit.manifest.StageRecord`);
5. says the stage's warnings on the terminal.

The workspace lock is the caller's (one command or one ``run`` holds it over many stages).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from toolkit.config import PipelineConfig
from toolkit.errors import StageError
from toolkit.layout import LogFiles, log_file_name
from toolkit.manifest import (
    Manifest,
    StageRecord,
    check_up_to_date,
    digest_files,
    file_sha256,
    require_finished,
)
from toolkit.stages.contract import Call, Made, Outcome, Recalled, Stage
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)


def _quiet(_: str) -> None:
    """No progress to show."""


def run_stage(
    spec: Stage,
    workspace: Workspace,
    config: PipelineConfig,
    *,
    log_id: str = "",
    overwrite: bool = False,
    step: Callable[[str], None] | None = None,
    **extra: Any,
) -> Outcome:
    """Run one stage (the module docstring) on one log (``log_id``) or the workspace.

    ``extra`` goes to a stage that still checks and records itself (:attr:`Stage.run`)."""
    if spec.run is not None:
        return spec.run(
            workspace, config, log_id=log_id, overwrite=overwrite, step=step or _quiet, **extra
        )
    if spec.compute is None or spec.recall is None:
        raise TypeError(f"stage {spec.name!r} declares neither run nor compute and recall")
    if spec.scope != "log":
        raise TypeError(f"stage {spec.name!r}: only per-log stages compute on the runner yet")
    start = time.perf_counter()
    workspace.require_log(log_id)
    with workspace.change_log(log_id) as gen:
        outcome = _fresh_or_computed(
            spec, workspace, config, LogFiles(gen.path), log_id, overwrite, step, start
        )
        if outcome.status != "up_to_date":
            gen.commit()
    logger = logging.getLogger(spec.compute.__module__)
    for warning in getattr(outcome, "warnings", ()):
        logger.warning("%s: %s", log_id, warning)
    return outcome


def _fresh_or_computed(
    spec: Stage,
    workspace: Workspace,
    config: PipelineConfig,
    files: LogFiles,
    log_id: str,
    overwrite: bool,
    step: Callable[[str], None] | None,
    start: float,
) -> Outcome:
    """Steps 2-4 of the module docstring, inside the log's directory ``files``."""
    assert spec.compute is not None and spec.recall is not None  # run_stage checked
    manifest = Manifest(files.manifest)
    settings = spec.settings_from(config)
    if spec.check is not None:
        spec.check(files, settings)
    inputs = hash_needs(spec, files, manifest)
    cfg_hash = spec.config_hash(config)
    record = manifest.stage(spec.name)
    if not overwrite and record is not None:
        written = [files.dir / o for o in record.outputs] or [files.path(m) for m in spec.makes]
        if check_up_to_date(record, inputs=inputs, config_hash=cfg_hash, outputs=written):
            header = manifest.read()
            seconds = time.perf_counter() - start
            return spec.recall(Recalled(log_id, record, header, settings, seconds))
    call = Call(
        workspace, log_id, settings, files, manifest, inputs, cfg_hash, start, step or _quiet
    )
    made = spec.compute(call)
    record_made(manifest, spec.name, made, inputs, cfg_hash, files.dir)
    return made.outcome


def hash_needs(spec: Stage, files: LogFiles, manifest: Manifest) -> dict[str, str]:
    """Layout name -> sha256 of every file ``spec`` needs that is there, each checked
    against the last finished run of the stage that makes it. StageError naming the first
    required file missing; WorkspaceError naming a file its maker did not write."""
    for need in spec.needs:
        path = files.path(need.name)
        if not need.optional and not path.is_file():
            raise StageError(f"input table missing; run `terrain {need.made_by}` first", path=path)
    inputs = {
        n.name: file_sha256(files.path(n.name)) for n in spec.needs if files.path(n.name).is_file()
    }
    by_maker: dict[str, dict[str, str]] = {}
    for need in spec.needs:
        if need.name in inputs:
            by_maker.setdefault(need.made_by, {})[log_file_name(need.name)] = inputs[need.name]
    for maker, made in by_maker.items():
        require_finished(manifest.stage(maker), maker, made, files.dir)
    return inputs


def record_made(
    manifest: Manifest,
    stage: str,
    made: Made,
    inputs: Mapping[str, str],
    cfg_hash: str,
    directory: Path,
) -> None:
    """Record a stage's run in ``manifest``: its header fields, then its record (inputs,
    configuration hash, outputs with their digests, rows, rejects, timings, warnings)."""
    if made.header:
        manifest.set_header(**made.header)
    manifest.record_stage(
        stage,
        StageRecord(
            inputs=dict(inputs),
            config_hash=cfg_hash,
            outputs=made.outputs,
            row_counts=dict(made.row_counts),
            rejects=dict(made.rejects),
            timings_s={k: round(v, 6) for k, v in sorted(made.timings_s.items())},
            warnings=made.warnings,
            output_files=digest_files(directory, made.outputs),
        ),
    )


__all__ = ["hash_needs", "record_made", "run_stage"]

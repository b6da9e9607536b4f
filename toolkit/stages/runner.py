"""The runner: what every stage needs done around its computation, done once.

For every stage, :func:`run_stage`

1. opens a new generation of the log (a per-log stage), committed in one atomic switch only
   when the stage computed something: killed at any moment, the log is as before or after;
2. hashes the files the stage needs (:attr:`Stage.needs`), refusing one missing, one its
   maker's last finished run did not write (changed, partial, left by an interrupted run),
   or one its maker made with another configuration, other code or other upstream files
   (:func:`check_needs`; a stage that gathers its inputs itself, tables over many logs,
   calls it per log);
3. hashes the configuration the stage reads and, unless ``overwrite``, compares both with
   the stage's last record and its outputs as written: when nothing changed it returns the
   stage's recalled outcome (``up_to_date``) without work;
4. otherwise calls the stage's compute function with its own frozen settings, and records
   what it read and wrote in the manifest (:class:`~toolkit.manifest.StageRecord`);
5. says the stage's warnings on the terminal.

A workspace stage does the same over the workspace's root and manifest (no generation: its
outputs are each published whole by atomic rename, the report as a generation of its own).

The workspace lock is the caller's (one command or one ``run`` holds it over many stages).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic

from toolkit.config import PipelineConfig
from toolkit.errors import StageError, ToolkitError, WorkspaceError
from toolkit.layout import LogFiles
from toolkit.manifest import (
    FileDigest,
    Manifest,
    StageRecord,
    check_up_to_date,
    code_changed,
    file_sha256,
    require_finished,
)
from toolkit.stages import registry
from toolkit.stages.contract import Call, Made, Need, OutcomeT, Recalled, SettingsT, Stage
from toolkit.workspace import Workspace


def _quiet(_: str) -> None:
    """No progress to show."""


def run_stage(
    spec: Stage[SettingsT, OutcomeT],
    workspace: Workspace,
    config: PipelineConfig,
    *,
    log_id: str = "",
    overwrite: bool = False,
    step: Callable[[str], None] | None = None,
    settings: SettingsT | None = None,
    source: Path | None = None,
) -> OutcomeT:
    """Run one stage (the module docstring) on one log (``log_id``) or the workspace.

    ``settings`` replaces the stage's own built from ``config`` (a test's smaller buffer);
    ``source`` is the file of a stage that starts a log (:attr:`Stage.locate`), which names
    the log itself. TypeError when what names the stage's scope is missing or misplaced."""
    _require_scope_arguments(spec, log_id, source)
    start = time.perf_counter()
    here = _Here(spec, workspace, config, log_id, overwrite, step or _quiet, start, settings)
    where = log_id
    if spec.scope == "workspace":
        outcome = here.fresh_or_computed(workspace.manifest(), workspace.root)
    elif source is not None:  # the stage that starts a log from its file (ingest)
        outcome, where = _start_log(here, source)
    else:
        workspace.require_log(log_id)
        with workspace.change_log(log_id) as gen:
            outcome = here.fresh_or_computed(Manifest(LogFiles(gen.path).manifest), gen.path)
            if outcome.status != "up_to_date":
                gen.commit()
    logger = logging.getLogger(spec.compute.__module__)
    for warning in getattr(outcome, "warnings", ()):
        if where:
            logger.warning("%s: %s", where, warning)
        else:
            logger.warning("%s", warning)
    return outcome


def _require_scope_arguments(spec: Stage[Any, Any], log_id: str, source: Path | None) -> None:
    """TypeError unless the run names what the stage's scope needs: a workspace stage no
    log, a log-starting stage its file (and no log id), any other per-log stage its log."""
    if spec.scope == "workspace":
        if log_id or source is not None:
            raise TypeError(f"stage {spec.name!r} runs over the workspace: pass no log_id")
    elif spec.starts_log:
        if source is None or log_id:
            raise TypeError(f"stage {spec.name!r} starts a log: pass source=, its file")
    elif not log_id or source is not None:
        raise TypeError(f"stage {spec.name!r} runs on one log: pass log_id=")


def _start_log(here: _Here[Any, OutcomeT], source: Path) -> tuple[OutcomeT, str]:
    """Run a stage that starts a log from its file: it names the log and hashes the file
    (:attr:`Stage.locate`); the workspace is made if need be, and the configuration, checked
    against the workspace's before anything is read, becomes the workspace's once the stage
    has worked with it. Returns the outcome and the file's name, for its warnings."""
    assert here.spec.locate is not None  # run_stage checked
    log_id, inputs, found = here.spec.locate(source)
    here = dataclasses.replace(here, log_id=log_id)
    workspace = here.workspace
    workspace.create()
    adopt_config = workspace.check_config(here.config, overwrite=here.overwrite)
    with workspace.change_log(log_id) as gen:
        manifest = Manifest(LogFiles(gen.path).manifest)
        outcome = here.fresh_or_computed(manifest, gen.path, (inputs, found))
        if outcome.status != "up_to_date":
            gen.commit()
    if adopt_config:  # only now, having worked with it, is it the workspace's
        workspace.write_config(here.config)
    return outcome, str(source)


@dataclass(frozen=True)
class _Here(Generic[SettingsT, OutcomeT]):
    """One run of one stage: what :meth:`fresh_or_computed` works with."""

    spec: Stage[SettingsT, OutcomeT]
    workspace: Workspace
    config: PipelineConfig
    log_id: str
    overwrite: bool
    step: Callable[[str], None]
    start: float
    settings: SettingsT | None = None

    def fresh_or_computed(
        self,
        manifest: Manifest,
        directory: Path,
        gathered: tuple[dict[str, str], Any] | None = None,
    ) -> OutcomeT:
        """Steps 2-4 of the module docstring: ``directory`` holds the stage's outputs (a
        log's new generation, or the workspace's root) and ``manifest`` its records;
        ``gathered`` the inputs' hashes and what was found with them, when known already."""
        spec = self.spec
        files = LogFiles(directory)
        settings = self.settings if self.settings is not None else spec.settings_from(self.config)
        if spec.check is not None:
            spec.check(files, settings)
        found: Any = None
        if gathered is not None:
            inputs, found = gathered
        elif spec.gather is not None:
            inputs, found = spec.gather(self.workspace, self.config)
        else:
            where = files.path if spec.scope == "log" else self.workspace.path
            inputs = check_needs(spec.needs, where, manifest, self.config, spec.name)
        cfg_hash = spec.config_hash(self.config)
        record = manifest.stage(spec.name)
        if not self.overwrite and record is not None:
            written = [directory / o for o in record.outputs] or [
                self._made_path(files, m) for m in spec.makes
            ]
            fresh = check_up_to_date(
                record,
                inputs=inputs,
                config_hash=cfg_hash,
                outputs=written,
                code_version=code_version_for(spec),
            )
            if fresh:
                seconds = time.perf_counter() - self.start
                last = Recalled(
                    self.log_id, record, manifest.read(), settings, seconds, self.workspace, found
                )
                return spec.recall(last)
        call = Call(
            self.workspace,
            self.log_id,
            settings,
            files,
            manifest,
            inputs,
            cfg_hash,
            self.start,
            self.step,
            found,
        )
        made = spec.compute(call)
        record_made(
            manifest,
            spec.name,
            made,
            inputs,
            cfg_hash,
            directory,
            code_version_for(spec),
            spec.hashed_sections(self.config),
        )
        return made.outcome

    def _made_path(self, files: LogFiles, name: str) -> Path:
        """Where an output of layout name ``name`` is: in the log, or in the workspace."""
        return files.path(name) if self.spec.scope == "log" else self.workspace.path(name)


def code_version_for(spec: Stage[Any, Any]) -> str:
    """The code version a stage's runs are keyed and recorded by: a registered stage's is
    its registry module's (:func:`toolkit.stages.registry.code_version_of`, which
    ``terrain logs`` reads without importing the stage); another's (a test's toy stage),
    that of its functions' modules (:attr:`Stage.code_version`)."""
    if spec.name in registry.names():
        return registry.code_version_of(spec.name)
    return spec.code_version


def remedy(stage: str, files: LogFiles, config: PipelineConfig) -> str:
    """How a log lacking ``stage``'s outputs would get them: "run `terrain STAGE` on it",
    or, when the stage's own check refuses the log (a role it needs that the log lacks, an
    IMU too slow for the shock band), that it cannot, and why: advice a user can follow."""
    spec = registry.stage(stage)
    if spec.check is not None:
        try:
            spec.check(files, spec.settings_from(config))
        except ToolkitError as exc:
            reason = str(exc.args[0]) if exc.args else str(exc)
            if exc.path is not None:  # the message without the path it starts with
                reason = reason.removeprefix(f"{exc.path}: ")
            return f"this log cannot feed {stage}: {reason}"
    return f"run `terrain {stage}` on it"


def hash_needs(
    spec: Stage[Any, Any], files: LogFiles, manifest: Manifest, config: PipelineConfig
) -> dict[str, str]:
    """A per-log stage's needs in the log ``files`` (:func:`check_needs`)."""
    return check_needs(spec.needs, files.path, manifest, config, spec.name)


def check_needs(
    needs: Sequence[Need],
    path_of: Callable[[str], Path],
    manifest: Manifest,
    config: PipelineConfig,
    reader: str,
) -> dict[str, str]:
    """Layout name -> sha256 of every file in ``needs`` that is there (``path_of`` says
    where a layout name is: in a log, or in the workspace; ``manifest`` holds their makers'
    records), each refused unless its maker's outputs are current. For each maker:

    - its last finished run wrote the file as it is now (:func:`require_finished`);
    - that run was made by this code with ``config`` (:func:`require_current`);
    - it was made from the same upstream files as the ones the reader reads beside it
      (:func:`require_same_upstream`: events labelled from another pose than the one the
      tables read; a model learned from other tables than the ones evaluate scores).

    The one place upstream freshness is checked, for every stage of either scope; ``terrain
    export`` holds the tables to it too. StageError naming the first required file missing;
    WorkspaceError naming a file or a maker's record that is not current."""
    inputs = hash_inputs(needs, path_of)
    require_inputs_current(needs, inputs, path_of, manifest, config, reader)
    return inputs


def hash_inputs(needs: Sequence[Need], path_of: Callable[[str], Path]) -> dict[str, str]:
    """Layout name -> sha256 of every file in ``needs`` that is there; StageError naming
    the first required file missing and the stage that makes it."""
    for need in needs:
        path = path_of(need.name)
        if not need.optional and not path.is_file():
            raise StageError(f"input table missing; run `terrain {need.made_by}` first", path=path)
    return {n.name: file_sha256(path_of(n.name)) for n in needs if path_of(n.name).is_file()}


def require_inputs_current(
    needs: Sequence[Need],
    inputs: Mapping[str, str],
    path_of: Callable[[str], Path],
    manifest: Manifest,
    config: PipelineConfig,
    reader: str,
) -> None:
    """The checks of :func:`check_needs` on ``inputs`` hashed already."""
    by_maker: dict[str, dict[str, str]] = {}
    for need in needs:
        if need.name in inputs:
            by_maker.setdefault(need.made_by, {})[need.name] = inputs[need.name]
    for maker, made in by_maker.items():
        record = manifest.stage(maker)
        directory = path_of(next(iter(made))).parent
        require_finished(record, maker, {path_of(n).name: h for n, h in made.items()}, directory)
        # A maker outside the registry (a test's toy stage) has no declaration to hold its
        # record against; every stage the command line runs is in it.
        if maker != reader and record is not None and maker in registry.names():
            require_current(record, registry.stage(maker), config, directory)
            require_same_upstream(record, maker, inputs, path_of)


def require_same_upstream(
    record: StageRecord, maker: str, inputs: Mapping[str, str], path_of: Callable[[str], Path]
) -> None:
    """Refuse a maker's outputs made from another version of a file the reader also reads:
    each input both read (by layout name) must have the same sha256 in the maker's record
    as now. Tyre paths from one pose matched against points placed with another, or scores
    of a model learned on other tables, would be quietly wrong. WorkspaceError naming the
    file."""
    for name, sha in inputs.items():
        if record.inputs.get(name, sha) != sha:
            raise WorkspaceError(
                f"the {maker} outputs beside it are stale (made from another {name} than "
                f"this one); run `terrain {maker}` again (or `terrain run`, which does)",
                path=path_of(name),
            )


def require_current(
    record: StageRecord, maker: Stage[Any, Any], config: PipelineConfig, directory: Path
) -> None:
    """Refuse the outputs of ``maker`` (its ``record``, in ``directory``) that its run with
    ``config`` and this code would not make: another configuration (``ingest --overwrite``
    with a new one left the workspace's other logs on the old) or another code made them.
    A stage run alone on them would mix the two; ``terrain run`` makes them again first.
    WorkspaceError naming the directory, the maker and what differs."""
    why = ""
    if record.config_hash != maker.config_hash(config):
        why = "made with another configuration than the one in force"
    elif record.code_version != code_version_for(maker):
        why = code_changed(record)
    if why:
        raise WorkspaceError(
            f"its {maker.name} outputs are stale ({why}); run `terrain {maker.name}` on it "
            "again (or `terrain run`, which does)",
            path=directory,
        )


def record_made(
    manifest: Manifest,
    stage: str,
    made: Made[Any],
    inputs: Mapping[str, str],
    cfg_hash: str,
    directory: Path,
    code_version: str = "",
    config_sections: tuple[str, ...] = (),
) -> None:
    """Record a stage's run in ``manifest``: its header fields, then its record (inputs,
    configuration hash, outputs with their digests, rows, rejects, timings, warnings, the
    version of the code that made them)."""
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
            # Keyed by file name, as the up-to-date check looks them up.
            output_files={Path(o).name: FileDigest.of(directory / o) for o in made.outputs},
            code_version=code_version,
            config_sections=tuple(config_sections),
        ),
    )


__all__ = [
    "check_needs",
    "code_version_for",
    "hash_inputs",
    "hash_needs",
    "record_made",
    "remedy",
    "require_current",
    "require_inputs_current",
    "require_same_upstream",
    "run_stage",
]

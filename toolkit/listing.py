"""``terrain logs``: what a workspace holds, log by log, from its manifests alone.

Each log: its id, the file it was ingested from (path, size), the per-log stages recorded
as finished, and the rows they wrote (pose rows, laser points, events); then the stages over
all logs (tables, learn, evaluate) with when they finished. Nothing is recomputed or hashed:
a listing of a season's workspace takes milliseconds per log. A recorded stage is marked
stale, with the reason, when what costs no hashing shows it: an output it wrote is gone, or
another version of its code made it (:mod:`toolkit.code_version`), or another
configuration than the workspace's (``ingest --overwrite`` with a new one leaves the other
logs on the old); ``terrain run`` makes those again. Whether its inputs still match is for
the stage itself to say (``terrain run`` skips those that do).

A log whose link points to nothing (its folder removed by hand or lost) is listed as
missing, naming that folder, with no stage done (its manifest went with it), and said on the
terminal; the workspace's stages are listed as their manifest records them either way.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from toolkit import strict_json
from toolkit.config import PipelineConfig, config_hash
from toolkit.errors import WorkspaceError
from toolkit.manifest import Manifest, StageRecord, code_changed, whole_number
from toolkit.stages import registry
from toolkit.workspace import Workspace, missing_log_problem

_log = logging.getLogger(__name__)


def _rows_shown() -> dict[str, str]:
    """Per-log stage -> the row count it is listed by (the first its summary shows)."""
    return {s.name: s.rows[0] for s in registry.stages() if s.scope == "log" and s.rows}


@dataclass(frozen=True)
class LogEntry:
    """One log of the workspace as its manifest records it; ``missing`` is the folder its
    link points to when that does not exist (None for a log that is there); ``stale`` the
    recorded stages whose outputs are stale, with why."""

    log_id: str
    source: str
    size_bytes: int | None
    stages: tuple[str, ...]
    rows: dict[str, int] = field(default_factory=dict)
    missing: str | None = None
    stale: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Listing:
    """The logs of a workspace and the stages over all of them (name -> finished, UTC),
    and which of those are stale, with why."""

    workspace: str
    logs: tuple[LogEntry, ...]
    workspace_stages: dict[str, str]
    workspace_stale: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The listing as a JSON document's fields."""
        return asdict(self)

    def to_json(self) -> str:
        """The listing as strict JSON (:func:`toolkit.strict_json.dumps`)."""
        return strict_json.dumps(self.to_dict())

    def text(self) -> str:
        """A table a person reads: a line per log, then the workspace stages."""
        later = registry.over_workspace()
        done_over = ", ".join(
            f"{s}{'*' if s in self.workspace_stale else ''} {self.workspace_stages[s]}"
            if s in self.workspace_stages
            else f"{s} -"
            for s in later
        )
        stale = [
            f"  {e.log_id} {stage}: {why}" for e in self.logs for stage, why in e.stale.items()
        ]
        stale += [f"  workspace {stage}: {why}" for stage, why in self.workspace_stale.items()]
        notes = ["* stale (`terrain run` makes it again):", *stale] if stale else []
        if not self.logs:
            if not self.workspace_stages:
                return f"{self.workspace}: no log yet (run `terrain ingest LOG.mcap -w WS`)"
            head = [f"{self.workspace}: no log in logs/", f"workspace: {done_over}"]
            return "\n".join(head + notes)
        per_log = registry.per_log()
        width = max(len(e.log_id) for e in self.logs)
        done_width = len(" ".join(per_log)) + len(per_log)
        lines = [f"{'log':<{width}}  {'stages done':<{done_width}}  rows  source"]
        for e in self.logs:
            done = " ".join(_done(s, e) for s in per_log)
            rows = ", ".join(f"{k} {v:,}" for k, v in e.rows.items()) or "-"
            source = e.source if e.missing is None else f"MISSING: {e.missing}"
            lines.append(f"{e.log_id:<{width}}  {done:<{done_width}}  {rows}  {source}")
        lines.append(f"workspace: {done_over}")
        return "\n".join(lines + notes)


def _done(stage: str, entry: LogEntry) -> str:
    """A stage's cell in the ``stages done`` column: its name (with ``*`` when stale), or
    dashes when it never finished."""
    if stage not in entry.stages:
        return "-" * len(stage)
    return f"{stage}{'*' if stage in entry.stale else ''}"


def _stale(
    record: StageRecord, stage: str, directory: Path, config: PipelineConfig | None
) -> str | None:
    """Why a recorded stage's outputs are stale, from what costs no hashing (an output
    gone, another code's, another configuration's than the workspace's ``config``), or
    None. ``directory``: where its outputs are recorded from."""
    for output in record.outputs:
        if not (directory / output).exists():
            return f"output missing: {output}"
    # Neither check imports the stage: the registry finds its code's version from the
    # source, and the record names the sections its configuration hash covers.
    if record.code_version != registry.code_version_of(stage):
        return code_changed(record)
    sections = record.config_sections
    if config is not None and sections and record.config_hash != config_hash(config, sections):
        return "made with another configuration than the workspace's"
    return None


def list_workspace(workspace: Workspace) -> Listing:
    """The :class:`Listing` of ``workspace`` (which must exist); each missing log said on
    the terminal."""
    workspace.require()
    config = workspace.read_config() if workspace.config_path.is_file() else None
    entries = {log_id: _entry(workspace, log_id, config) for log_id in workspace.log_ids()}
    for log_id, target in workspace.missing_logs().items():
        _log.warning("%s: %s", workspace.log_dir(log_id), missing_log_problem(target))
        entries[log_id] = LogEntry(log_id, "", None, (), missing=str(target))
    overall = workspace.manifest().stages()
    done = [s for s in registry.over_workspace() if s in overall]
    stale = {s: _stale(overall[s], s, workspace.root, config) for s in done}
    return Listing(
        workspace=str(workspace.root),
        logs=tuple(entries[k] for k in sorted(entries)),
        workspace_stages={s: overall[s].finished_utc or "done" for s in done},
        workspace_stale={s: why for s, why in stale.items() if why is not None},
    )


def _entry(workspace: Workspace, log_id: str, config: PipelineConfig | None) -> LogEntry:
    """The :class:`LogEntry` of a log that is there, from its manifest (stale against the
    workspace's ``config``)."""
    per_log, shown = registry.per_log(), _rows_shown()
    manifest = Manifest(workspace.log_manifest_path(log_id))
    found = manifest.read().get("source")
    source: dict[str, Any] = found if isinstance(found, dict) else {}
    records = manifest.stages()
    rows = {
        shown[s]: int(records[s].row_counts.get(shown[s], 0))
        for s in per_log
        if s in records and s in shown
    }
    done = tuple(s for s in per_log if s in records)
    stale = {s: _stale(records[s], s, manifest.path.parent, config) for s in done}
    return LogEntry(
        log_id=log_id,
        source=str(source.get("path", "")),
        size_bytes=_source_size(source, manifest.path),
        stages=done,
        rows=rows,
        stale={s: why for s, why in stale.items() if why is not None},
    )


def _source_size(source: dict[str, Any], manifest: Path) -> int | None:
    """The size the manifest records of the log's file (None when it records none); a
    WorkspaceError naming the manifest and the field when it is no size."""
    size = source.get("size_bytes")
    if size is None:
        return None
    try:
        return whole_number(size, "source.size_bytes")
    except ValueError as exc:
        raise WorkspaceError(f"malformed manifest: {exc}", path=manifest) from None


__all__ = ["Listing", "LogEntry", "list_workspace"]

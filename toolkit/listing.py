"""``terrain logs``: what a workspace holds, log by log, from its manifests alone.

Each log: its id, the file it was ingested from (path, size), the per-log stages recorded
as finished, and the rows they wrote (pose rows, laser points, events); then the stages over
all logs (tables, learn, evaluate) with when they finished. Nothing is recomputed or hashed:
a listing of a season's workspace takes milliseconds per log. Whether a recorded stage is
still up to date is for the stage itself to say (``terrain run`` skips those that are).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from toolkit.manifest import Manifest
from toolkit.pipeline import PER_LOG_STAGES, STAGES
from toolkit.workspace import Workspace

#: The row count each per-log stage is listed by.
ROWS_SHOWN = {"pose": "pose", "project": "points", "label": "events"}


@dataclass(frozen=True)
class LogEntry:
    """One log of the workspace as its manifest records it."""

    log_id: str
    source: str
    size_bytes: int | None
    stages: tuple[str, ...]
    rows: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Listing:
    """The logs of a workspace and the stages over all of them (name -> finished, UTC)."""

    workspace: str
    logs: tuple[LogEntry, ...]
    workspace_stages: dict[str, str]

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    def text(self) -> str:
        """A table a person reads: a line per log, then the workspace stages."""
        if not self.logs:
            return f"{self.workspace}: no log yet (run `terrain ingest LOG.mcap -w WS`)"
        width = max(len(e.log_id) for e in self.logs)
        lines = [f"{'log':<{width}}  {'stages done':<27}  rows  source"]
        for e in self.logs:
            done = " ".join(s if s in e.stages else "-" * len(s) for s in PER_LOG_STAGES)
            rows = ", ".join(f"{k} {v:,}" for k, v in e.rows.items()) or "-"
            lines.append(f"{e.log_id:<{width}}  {done:<27}  {rows}  {e.source}")
        later = [s for s in STAGES if s not in PER_LOG_STAGES]
        lines.append(
            "workspace: "
            + ", ".join(
                f"{s} {self.workspace_stages[s]}" if s in self.workspace_stages else f"{s} -"
                for s in later
            )
        )
        return "\n".join(lines)


def list_workspace(workspace: Workspace) -> Listing:
    """The :class:`Listing` of ``workspace`` (which must exist)."""
    workspace.require()
    entries = []
    for log_id in workspace.log_ids():
        raw: dict[str, Any] = Manifest(workspace.log_manifest_path(log_id)).read()
        found = raw.get("source")
        source: dict[str, Any] = found if isinstance(found, dict) else {}
        records = Manifest(workspace.log_manifest_path(log_id)).stages()
        rows = {
            ROWS_SHOWN[s]: int(records[s].row_counts.get(ROWS_SHOWN[s], 0))
            for s in PER_LOG_STAGES
            if s in records and s in ROWS_SHOWN
        }
        entries.append(
            LogEntry(
                log_id=log_id,
                source=str(source.get("path", "")),
                size_bytes=source.get("size_bytes"),
                stages=tuple(s for s in PER_LOG_STAGES if s in records),
                rows=rows,
            )
        )
    overall = workspace.manifest().stages()
    return Listing(
        workspace=str(workspace.root),
        logs=tuple(entries),
        workspace_stages={
            s: overall[s].finished_utc or "done"
            for s in STAGES[len(PER_LOG_STAGES) :]
            if s in overall
        },
    )


__all__ = ["Listing", "LogEntry", "list_workspace"]

"""``terrain run``: every stage, in dependency order, skipping what is up to date.

The stages and what each needs::

    ingest -> pose -> project -> label      per log: each log on its own, logs in parallel
                          \\-------\\-> tables -> learn -> evaluate     over the workspace

The per-log stages run stage by stage (all logs' ingest, then all logs' pose, ...) through
the same executors as ``terrain ingest`` (:mod:`toolkit.batch`: a local process pool by
default, a Dask cluster with ``--executor dask``, ``--shard-index/--num-shards`` for job
arrays); a log that fails a stage is reported and left out of the later ones, the other logs
go on. The workspace stages then run in this process, each only if every earlier stage
succeeded.

**Skipping.** Nothing here decides what is current: every stage checks its own recorded
inputs, configuration and outputs (by size and sha256) and reports ``up_to_date`` without
work when they match (:func:`toolkit.manifest.check_up_to_date`). A second ``run`` on the
same logs and configuration therefore does nothing, and ``--overwrite`` hands each stage its
own ``overwrite``.

**Interrupted runs.** Every stage writes aside and publishes by rename, per-log stages swap a
whole new generation of the log's directory, and a stage is recorded only once its outputs
are in place. A run killed at any moment (even SIGKILL) leaves each output either as it was
or as the stage made it, and the next run redoes exactly the stages whose outputs are not
recorded as current; since every stage is deterministic, it finishes with the same outputs
as an uninterrupted run.

**Shards.** With ``--num-shards K > 1`` a job runs the per-log stages of its share of the logs
and stops: the workspace stages need every log, so they run once all shards are done
(``terrain run LOGS... -w WS --from tables``). Shards share the workspace lock; an unsharded
run holds it exclusively.

The final summary gives, per stage, its wall time, how many logs (or the workspace) it did
or found up to date, the rows it wrote, what it rejected by reason and its warnings, all read
from the manifests the stages wrote.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toolkit.batch import (
    BatchSummary,
    _config_in_force,
    make_executor,
    run_batch,
    stage_task,
    this_shard,
)
from toolkit.errors import ToolkitError, WorkspaceError
from toolkit.manifest import Manifest
from toolkit.progress import note, progress
from toolkit.stages import registry
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace, log_id_for

_log = logging.getLogger(__name__)


def stage_range(first: str | None, last: str | None) -> tuple[str, ...]:
    """The registry's stages from ``first`` to ``last`` inclusive (default: all).
    WorkspaceError if they are unknown or out of order."""
    names = registry.names()
    for name in (first, last):
        if name is not None and name not in names:
            raise WorkspaceError(f"no stage named {name!r} (stages: {', '.join(names)})")
    i = names.index(first) if first else 0
    j = names.index(last) if last else len(names) - 1
    if i > j:
        raise WorkspaceError(f"--from {first} comes after --to {last}")
    return names[i : j + 1]


@dataclass(frozen=True)
class StageReport:
    """One stage of a run: wall time; per status (``done``, ``up_to_date``, ``failed``)
    how many logs (or 1 for a workspace stage); rows written, rejects by reason and
    warnings, summed over the logs from their manifests; failures item -> reason."""

    stage: str
    seconds: float
    statuses: dict[str, int]
    rows: dict[str, int] = field(default_factory=dict)
    rejects: dict[str, int] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    failures: dict[str, str] = field(default_factory=dict)

    def line(self) -> str:
        status = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in self.statuses.items() if n)
        # A stage no log reached (each failed an earlier one) says so, not an empty row.
        status = status or "not run: no log passed the stage before"
        rows = ", ".join(f"{k} {v:,}" for k, v in list(self.rows.items())[:3])
        rejected = sum(self.rejects.values())
        parts = [f"{self.stage:<9} {self.seconds:7.1f} s  {status}"]
        if rows:
            parts.append(f"rows: {rows}")
        if rejected:
            top = ", ".join(f"{k} {v:,}" for k, v in sorted(self.rejects.items()) if v)
            parts.append(f"rejects: {top}")
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning{'s' if len(self.warnings) != 1 else ''}")
        return "; ".join(parts)


@dataclass(frozen=True)
class RunSummary:
    """What ``terrain run`` did, stage by stage."""

    stages: tuple[StageReport, ...]
    log_ids: tuple[str, ...]
    seconds: float
    report: Path | None
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return all(not s.failures for s in self.stages)

    def to_dict(self) -> dict[str, Any]:
        """What ``terrain run --json`` prints: every stage's report, the logs, the time, the
        notes and the report's page (None when not written)."""
        return {
            "ok": self.ok,
            "stages": [dataclasses.asdict(s) for s in self.stages],
            "log_ids": list(self.log_ids),
            "seconds": round(self.seconds, 3),
            "notes": list(self.notes),
            "report": str(self.report)
            if self.report is not None and self.report.is_file()
            else None,
        }

    def render(self) -> str:
        lines = [s.line() for s in self.stages]
        lines.append(f"run: {len(self.log_ids)} log(s) in {self.seconds:.1f} s")
        lines.extend(self.notes)
        if self.report is not None and self.report.is_file():
            lines.append(f"report: {self.report}")
        return "\n".join(lines)


def _record_totals(
    records: Sequence[dict[str, Any]], stage: str
) -> tuple[dict[str, int], dict[str, int], tuple[str, ...]]:
    rows: dict[str, int] = {}
    rejects: dict[str, int] = {}
    warnings: list[str] = []
    keys = registry.stage(stage).rows
    for rec in records:
        counts = rec.get("row_counts", {})
        if keys is None:
            rows["total"] = rows.get("total", 0) + sum(int(v) for v in counts.values())
        else:
            for k in keys:
                if k in counts:
                    rows[k] = rows.get(k, 0) + int(counts[k])
        for k, v in rec.get("rejects", {}).items():
            rejects[k] = rejects.get(k, 0) + int(v)
        warnings.extend(str(w) for w in rec.get("warnings", ()))
    return rows, rejects, tuple(warnings)


def _log_records(ws: Workspace, log_ids: Sequence[str], stage: str) -> list[dict[str, Any]]:
    out = []
    for log_id in log_ids:
        rec = Manifest(ws.log_manifest_path(log_id)).read().get("stages", {}).get(stage)
        if isinstance(rec, dict):
            out.append(rec)
    return out


def _per_log_report(
    stage: str, summary: BatchSummary, ws: Workspace, ids: Sequence[str]
) -> StageReport:
    statuses = {
        "done": len(summary.done),
        "up_to_date": len(summary.up_to_date),
        "failed": len(summary.failed),
    }
    rows, rejects, warnings = _record_totals(_log_records(ws, ids, stage), stage)
    failures = {
        str(item[0] if isinstance(item, tuple) else item): reason
        for item, reason in summary.failed.items()
    }
    return StageReport(stage, summary.seconds, statuses, rows, rejects, warnings, failures)


def run_pipeline(
    logs: Sequence[Path],
    workspace_root: Path,
    config_path: Path | None,
    *,
    first: str | None = None,
    last: str | None = None,
    overwrite: bool = False,
    executor_kind: str = "local",
    scheduler: str | None = None,
    workers: int | None = None,
    shard_index: int = 0,
    num_shards: int = 1,
    executor: Executor | None = None,
    echo: Callable[[str], None] | None = None,
) -> RunSummary:
    """``terrain run`` (module docstring). ``echo`` receives each stage's line as it ends."""
    start = time.perf_counter()
    say = echo or note  # each stage's line as it ends: off a terminal by default
    stages = stage_range(first, last)
    unique, mine = this_shard(logs, shard_index, num_shards)
    ws = Workspace(workspace_root)
    # Validated before anything is made: a bad configuration leaves no workspace.
    config = _config_in_force(ws, config_path)
    with ws.created():  # a first run that ingests no log leaves no workspace
        adopt_config = ws.check_config(config, overwrite=overwrite)
        root = os.path.abspath(workspace_root)
        cwd = os.getcwd()
        per_log = [s for s in stages if registry.stage(s).scope == "log"]
        over_ws = [s for s in stages if s not in per_log]
        workspace_stages = over_ws if num_shards == 1 else []
        starts = registry.stage(per_log[0]).starts_log if per_log else False
        notes: list[str] = []
        if num_shards > 1 and over_ws:
            notes.append(
                f"shard {shard_index} of {num_shards}: per-log stages only for {len(mine)} of "
                f"{len(unique)} logs; once every shard is done, run `terrain run LOGS... -w "
                f"{workspace_root} --from tables`"
            )
        reports: list[StageReport] = []
        # Items are (path, log id); the id is known once ingested (or, when ingest is not part
        # of this run, from the file's content, as ingest names it).
        items: list[tuple[str, str]] = [(str(p), "") for p in mine]
        if per_log and not starts:
            items = [(str(p), log_id_for(p)) for p in mine]
            missing = [i for _, i in items if i not in ws.log_ids()]
            if missing:
                raise WorkspaceError(
                    f"not ingested: {', '.join(missing)} (run from ingest)", path=ws.root
                )
        ids: list[str] = [i for _, i in items]
        every = items  # the logs a stage may take: those its source stage (ingest) passed
        with contextlib.ExitStack() as stack:
            stack.enter_context(ws.lock(shared=num_shards > 1))
            pool = executor
            if pool is None and per_log:
                pool = stack.enter_context(
                    make_executor(executor_kind, workers=workers, scheduler=scheduler)
                )
            total = len(items) * len(per_log) + len(workspace_stages)
            with progress(total=total, desc="run", unit="step") as bar:
                passed: dict[str, list[tuple[str, str]]] = {}
                for stage in per_log:
                    # A stage takes the logs its prerequisites passed: label needs pose, not
                    # project, so a log without lasers is still labelled.
                    spec = registry.stage(stage)
                    needed = [set(passed[b]) for b in spec.after if b in passed]
                    items = [it for it in every if all(it in ok for ok in needed)]
                    task = functools.partial(
                        stage_task,
                        stage=stage,
                        workspace_root=root,
                        config=config,
                        overwrite=overwrite,
                        cwd=cwd,
                    )
                    if pool is None:  # opened above whenever a per-log stage runs
                        raise RuntimeError("no executor for the per-log stages")
                    summary = run_batch(task, items, pool, desc=stage, unit="log", bar=bar)
                    if adopt_config and summary.results:
                        ws.write_config(config)  # a config becomes the workspace's once it worked
                        adopt_config = False
                    if spec.starts_log:  # the log ids are known once it has read the files
                        results = summary.results
                        items = [
                            (p, str(results[(p, i)].log_id)) for p, i in items if (p, i) in results
                        ]
                        every = items
                    else:
                        ok = summary.results
                        items = [it for it in items if it in ok]
                    passed[stage] = items
                    ids = sorted({i for done in passed.values() for _, i in done})
                    report = _per_log_report(stage, summary, ws, [i for _, i in items])
                    reports.append(report)
                    say(report.line())
                report_path: Path | None = None
                for stage in workspace_stages:
                    t0 = time.perf_counter()
                    if any(r.failures for r in reports):
                        # Tables reads every log of the workspace: one whose stage just failed
                        # would enter with its older outputs. Stop, as the docstring says.
                        notes.append("workspace stages not run: a log failed a per-log stage")
                        break
                    try:
                        spec = registry.stage(stage)
                        result = run_stage(spec, ws, config, overwrite=overwrite)
                    except ToolkitError as exc:
                        reports.append(
                            StageReport(
                                stage,
                                time.perf_counter() - t0,
                                {"failed": 1},
                                failures={stage: " ".join(str(exc).split())},
                            )
                        )
                        say(reports[-1].line())
                        break
                    finally:
                        bar.update(1)
                    status = "up_to_date" if result.status == "up_to_date" else "done"
                    rec = ws.manifest().read().get("stages", {}).get(stage, {})
                    rows, rejects, warnings = _record_totals([rec], stage)
                    reports.append(
                        StageReport(
                            stage, time.perf_counter() - t0, {status: 1}, rows, rejects, warnings
                        )
                    )
                    say(reports[-1].line())
                    if "index" in spec.makes:
                        report_path = ws.index_path
        if adopt_config and any(
            r.statuses.get("done") or r.statuses.get("up_to_date") for r in reports
        ):
            ws.write_config(config)  # the configuration in force is the one these stages used
        all_ids = tuple(sorted(set(ids) if per_log else ws.log_ids()))
        return RunSummary(
            tuple(reports),
            all_ids,
            time.perf_counter() - start,
            report_path,
            tuple(notes),
        )


__all__ = ["RunSummary", "StageReport", "run_pipeline", "stage_range"]

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
    LOCAL,
    BatchSummary,
    Executors,
    begin_batch,
    run_batch,
    stage_task,
)
from toolkit.config import PipelineConfig
from toolkit.errors import ToolkitError, WorkspaceError
from toolkit.manifest import Manifest
from toolkit.progress import note, progress
from toolkit.stages import registry
from toolkit.stages.contract import Stage
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

    def render(self, *, stages: bool = True) -> str:
        """The summary a person reads: a line per stage (left out with ``stages=False``,
        when each was said as it ended), the totals, the notes and where the report is."""
        lines = [s.line() for s in self.stages] if stages else []
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


Item = tuple[str, str]
"""A log as the per-log stages take it: (path, log id)."""


@dataclass
class _RunLogs:
    """The logs of a run, as :data:`Item`; the id is known once ingested (or, when ingest is
    not part of this run, from the file's content, as ingest names it). ``every``: the logs a
    stage may take (those its source stage, ingest, passed); ``passed``: each stage's."""

    every: list[Item]
    passed: dict[str, list[Item]] = field(default_factory=dict)

    @classmethod
    def of(cls, mine: Sequence[Path], ws: Workspace, *, named: bool) -> _RunLogs:
        """This shard's logs; ``named``: their ids now, from their content (the run does
        not ingest them), WorkspaceError unless each is ingested already."""
        if not named:
            return cls([(str(p), "") for p in mine])
        items = [(str(p), log_id_for(p)) for p in mine]
        missing = [i for _, i in items if i not in ws.log_ids()]
        if missing:
            raise WorkspaceError(
                f"not ingested: {', '.join(missing)} (run from ingest)", path=ws.root
            )
        return cls(items)

    def for_stage(self, spec: Stage[Any, Any]) -> list[Item]:
        """The logs its prerequisites passed: label needs pose, not project, so a log
        without lasers is still labelled."""
        needed = [set(self.passed[b]) for b in spec.after if b in self.passed]
        return [it for it in self.every if all(it in ok for ok in needed)]

    def record(
        self, spec: Stage[Any, Any], items: list[Item], results: dict[Any, Any]
    ) -> list[Item]:
        """The logs the stage passed (those with a result), kept for the stages after it;
        a source stage's with the ids it gave them (it has read the files)."""
        if spec.starts_log:
            items = [(p, str(results[(p, i)].log_id)) for p, i in items if (p, i) in results]
            self.every = items
        else:
            items = [it for it in items if it in results]
        self.passed[spec.name] = items
        return items

    def ids(self) -> list[str]:
        """Every log id a stage of this run passed."""
        return sorted({i for done in self.passed.values() for _, i in done})


@dataclass
class _Run:
    """One ``terrain run`` under way: its workspace, its configuration (written as the
    workspace's once a stage used it, when ``adopt_config``), the stages' reports so far
    (each said as it ends) and the notes for the summary."""

    ws: Workspace
    config: PipelineConfig
    overwrite: bool
    adopt_config: bool
    say: Callable[[str], None]
    root: str = ""  # the workspace's absolute path, for the stage tasks
    cwd: str = ""  # where the run started: the tasks take relative log paths against it
    reports: list[StageReport] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def per_log_stage(self, stage: str, logs: _RunLogs, pool: Executor | None, bar: Any) -> None:
        """Run a per-log stage on the logs its prerequisites passed, through ``pool``."""
        spec = registry.stage(stage)
        items = logs.for_stage(spec)
        task = functools.partial(
            stage_task,
            stage=stage,
            workspace_root=self.root,
            config=self.config,
            overwrite=self.overwrite,
            cwd=self.cwd,
        )
        if pool is None:  # opened whenever a per-log stage runs
            raise RuntimeError("no executor for the per-log stages")
        summary = run_batch(task, items, pool, desc=stage, unit="log", bar=bar)
        if self.adopt_config and summary.results:
            self.ws.write_config(self.config)  # a config becomes the workspace's once it worked
            self.adopt_config = False
        items = logs.record(spec, items, summary.results)
        self._report(_per_log_report(stage, summary, self.ws, [i for _, i in items]))

    def workspace_stages(self, stages: Sequence[str], bar: Any) -> Path | None:
        """Run the workspace stages in order until one fails; the report's page if one of
        them makes it. None run after a log failed a per-log stage: tables reads every log
        of the workspace, and one whose stage just failed would enter with older outputs."""
        report_path: Path | None = None
        for k, stage in enumerate(stages):
            if any(r.failures for r in self.reports):
                self.notes.append("workspace stages not run: a log failed a per-log stage")
                break
            spec = registry.stage(stage)
            bar.set_description(stage)
            if not self._workspace_stage(stage, spec, bar):
                later = stages[k + 1 :]
                if later:  # said, as a per-log stage no log reached is
                    self.notes.append(
                        f"{', '.join(later)} not run: {stage} failed (its error is below)"
                    )
                break
            if "index" in spec.makes:
                report_path = self.ws.index_path
        return report_path

    def _workspace_stage(self, stage: str, spec: Stage[Any, Any], bar: Any) -> bool:
        """Run one workspace stage and report it; whether it succeeded."""
        t0 = time.perf_counter()
        try:
            result = run_stage(spec, self.ws, self.config, overwrite=self.overwrite)
        except ToolkitError as exc:
            reason = " ".join(str(exc).split())
            self._report(
                StageReport(
                    stage, time.perf_counter() - t0, {"failed": 1}, failures={stage: reason}
                )
            )
            return False
        finally:
            bar.update(1)
        status = "up_to_date" if result.status == "up_to_date" else "done"
        rec = self.ws.manifest().read().get("stages", {}).get(stage, {})
        rows, rejects, warnings = _record_totals([rec], stage)
        self._report(
            StageReport(stage, time.perf_counter() - t0, {status: 1}, rows, rejects, warnings)
        )
        return True

    def adopt_config_if_used(self) -> None:
        """The configuration in force is the one these stages used: the workspace's, once
        any stage did (or found up to date) its work with it."""
        if self.adopt_config and any(
            r.statuses.get("done") or r.statuses.get("up_to_date") for r in self.reports
        ):
            self.ws.write_config(self.config)

    def _report(self, report: StageReport) -> None:
        self.reports.append(report)
        self.say(report.line())


def run_pipeline(
    logs: Sequence[Path],
    workspace_root: Path,
    config_path: Path | None,
    *,
    first: str | None = None,
    last: str | None = None,
    overwrite: bool = False,
    executors: Executors = LOCAL,
    executor: Executor | None = None,
    echo: Callable[[str], None] | None = None,
) -> RunSummary:
    """``terrain run`` (module docstring). ``echo`` receives each stage's line as it ends."""
    start = time.perf_counter()
    stages = stage_range(first, last)
    shard_index, num_shards = executors.shard_index, executors.num_shards
    with begin_batch(
        logs, workspace_root, config_path, overwrite=overwrite, executors=executors
    ) as begun:
        ws, unique, mine = begun.workspace, begun.unique, begun.mine
        # Each stage's line as it ends: off a terminal by default.
        run = _Run(
            ws,
            begun.config,
            overwrite,
            begun.adopt_config,
            echo or note,
            root=os.path.abspath(workspace_root),
            cwd=os.getcwd(),
        )
        per_log = [s for s in stages if registry.stage(s).scope == "log"]
        over_ws = [s for s in stages if s not in per_log]
        workspace_stages = over_ws if num_shards == 1 else []
        if num_shards > 1 and over_ws:
            run.notes.append(
                f"shard {shard_index} of {num_shards}: per-log stages only for {len(mine)} of "
                f"{len(unique)} logs; once every shard is done, run `terrain run LOGS... -w "
                f"{workspace_root} --from tables`"
            )
        starts = registry.stage(per_log[0]).starts_log if per_log else False
        run_logs = _RunLogs.of(mine, ws, named=bool(per_log) and not starts)
        with contextlib.ExitStack() as stack:
            stack.enter_context(ws.lock(shared=num_shards > 1))
            pool = executor
            if pool is None and per_log:
                pool = stack.enter_context(executors.open())
            total = len(run_logs.every) * len(per_log) + len(workspace_stages)
            with progress(total=total, desc="run", unit="step") as bar:
                for stage in per_log:
                    bar.set_description(stage)  # the bar names the stage it counts
                    run.per_log_stage(stage, run_logs, pool, bar)
                report_path = run.workspace_stages(workspace_stages, bar)
        run.adopt_config_if_used()
        all_ids = tuple(run_logs.ids() if per_log else sorted(ws.log_ids()))
        return RunSummary(
            tuple(run.reports),
            all_ids,
            time.perf_counter() - start,
            report_path,
            tuple(run.notes),
        )


__all__ = ["RunSummary", "StageReport", "run_pipeline", "stage_range"]

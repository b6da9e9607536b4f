"""One command per registered stage (:mod:`toolkit.stages.registry`): a per-log stage on
one log or every log of the workspace, a workspace stage over the workspace."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from toolkit.cli.base import WORKSPACE_OPTION, error_line, workspace_option
from toolkit.cli.json_out import emit
from toolkit.errors import ToolkitError
from toolkit.stages import registry

if TYPE_CHECKING:
    from toolkit.config import PipelineConfig
    from toolkit.stages.contract import Stage
    from toolkit.workspace import Workspace

JSON_HELP = "Print the result as JSON on stdout (each log's status, summary and record)."


class StageName(click.ParamType):  # type: ignore[type-arg]
    """A registered stage's name (:mod:`toolkit.stages.registry`), checked when parsed."""

    name = "stage"

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        return "[" + "|".join(registry.names()) + "]"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        if value in registry.names():
            return str(value)
        self.fail(f"{value!r} is not a stage: {', '.join(registry.names())}", param, ctx)


def stage_command(name: str) -> click.Command:
    """The command of registered stage ``name``: per log (-w, --log, --overwrite, --json)
    or over the workspace (-w, --overwrite, --json)."""
    line = registry.listed(name)
    per_log = line.scope == "log"

    def callback(
        workspace: Path, overwrite: bool, as_json: bool, log_id: str | None = None
    ) -> None:
        if per_log:
            each_log(workspace, log_id, name, overwrite, as_json)
        else:
            workspace_stage(name, workspace, overwrite, as_json)

    f = click.option("--json", "as_json", is_flag=True, help=JSON_HELP)(callback)
    f = click.option("--overwrite", is_flag=True, help="Run it again even if it is up to date.")(f)
    if not per_log:
        return click.command(name, help=line.help)(WORKSPACE_OPTION(f))
    f = click.option("--log", "log_id", default=None, help="One log id (default: every log).")(f)
    f = workspace_option("Workspace directory (ingested).")(f)
    return click.command(name, help=line.help)(f)


def each_log(
    workspace: Path, log_id: str | None, verb: str, overwrite: bool, as_json: bool = False
) -> None:
    """Run a per-log stage on one log or every log of the workspace, under its lock: one
    summary line per log, one error line per failed log (the others still run), a total
    line for several logs, exit 1 when any failed. With ``as_json`` the summary lines are
    one JSON document instead (:func:`_log_entry`); the error lines stay on stderr."""
    from toolkit.workspace import Workspace

    spec = registry.stage(verb)
    ws = Workspace(workspace)
    cfg = ws.read_config()
    ids = ws.log_ids()
    if log_id is not None:
        ws.require_log(log_id)
        ids = [log_id]
    if not ids:
        message = f"nothing to {verb}: no ingested log in {ws.root} (run `terrain ingest` first)"
        if as_json:
            emit({"stage": verb, "logs": [], "summary": message})
        else:
            click.echo(message)
        return
    with ws.lock():
        results = [_one_log(spec, ws, cfg, one, overwrite, as_json) for one in ids]
    failed = sum(r["status"] == "failed" for r in results)
    if as_json:
        emit({"stage": verb, "logs": results}, ok=not failed)
    elif len(ids) > 1 or failed:
        done: dict[str, int] = {}
        for r in results:
            if r["status"] != "failed":
                done[r["status"]] = done.get(r["status"], 0) + 1
        parts = [f"{n} {status.replace('_', ' ')}" for status, n in sorted(done.items())]
        logs = f"{len(ids)} log{'s' if len(ids) != 1 else ''}"
        click.echo(f"{verb}: {logs}: {', '.join(parts + [f'{failed} failed'])}")
    if failed:
        raise click.exceptions.Exit(1)


def _one_log(
    spec: Stage[Any, Any],
    ws: Workspace,
    cfg: PipelineConfig,
    log_id: str,
    overwrite: bool,
    as_json: bool,
) -> dict[str, Any]:
    """Run the stage on one log and say it (its summary line, or an error line when it
    fails: one log's failure never stops the others); its entry of the JSON document."""
    from toolkit.manifest import Manifest
    from toolkit.stages.runner import run_stage

    try:
        result = run_stage(spec, ws, cfg, log_id=log_id, overwrite=overwrite)
    except ToolkitError as exc:
        error_line(f"{log_id}: {exc}")
        return {"log_id": log_id, "status": "failed", "error": str(exc)}
    if not as_json:
        click.echo(spec.describe(result))
    record = Manifest(ws.log_manifest_path(log_id)).stage(spec.name)
    return {
        "log_id": log_id,
        "status": result.status,
        "summary": spec.describe(result),
        "record": record.to_json() if record is not None else None,
    }


def workspace_stage(name: str, workspace: Path, overwrite: bool, as_json: bool) -> None:
    """Run a workspace stage under the workspace's lock, with its progress, and say it."""
    from toolkit.progress import progress
    from toolkit.stages.runner import run_stage
    from toolkit.workspace import Workspace

    spec = registry.stage(name)
    ws = Workspace(workspace)
    cfg = ws.read_config()
    total = spec.progress_total(cfg) if spec.progress_total is not None else None
    with ws.lock(), progress(total=total, desc=name, unit=spec.unit) as bar:

        def step(what: str) -> None:
            if what:
                bar.set_postfix_str(what)
            bar.update(1)

        result = run_stage(spec, ws, cfg, overwrite=overwrite, step=step)
    _echo_stage(ws, name, result.status, spec.describe(result), as_json)


def _echo_stage(ws: Workspace, stage: str, status: str, text: str, as_json: bool) -> None:
    """A workspace stage's result: its summary text, or with ``as_json`` a JSON document of
    the stage, its status, that text and its manifest record (rows, rejects, timings,
    warnings, inputs' sha256)."""
    if not as_json:
        click.echo(text)
        return
    record = ws.manifest().stage(stage)
    doc = {
        "stage": stage,
        "status": status,
        "summary": text,
        "record": record.to_json() if record is not None else None,
    }
    emit(doc)

"""The verbs that start from MCAP files and run logs in parallel: ``ingest`` and ``run``,
with their executor (local pool or Dask) and shard options."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from toolkit.cli.base import debug_on, error_line
from toolkit.cli.group import main
from toolkit.cli.json_out import emit, status_word
from toolkit.cli.stages import StageName

if TYPE_CHECKING:  # the runners load numpy and pyarrow: imported when a verb runs
    from toolkit.batch import Executors

Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


@dataclass(frozen=True)
class BatchArgs:
    """A verb's logs, workspace and configuration (the first arguments of
    :func:`~toolkit.batch.run_ingest_batch` and :func:`~toolkit.pipeline.run_pipeline`),
    with its executor and shard options."""

    logs: list[Path]
    workspace: Path
    config_path: Path | None
    executors: Executors


def _check_executor_options(ctx: click.Context, executors: Executors) -> None:
    """Usage errors among the executor and shard options (exit 2)."""
    executor_kind, scheduler = executors.executor_kind, executors.scheduler
    if executor_kind == "dask" and not scheduler:
        raise click.UsageError("--executor dask needs --scheduler ADDR", ctx)
    if executor_kind != "dask" and scheduler is not None:
        raise click.UsageError("--scheduler applies only with --executor dask", ctx)
    shard_index, num_shards = executors.shard_index, executors.num_shards
    if shard_index >= num_shards:
        raise click.BadParameter(
            f"{shard_index} is not below --num-shards {num_shards}",
            ctx,
            param_hint="'--shard-index'",
        )


def _require_log_files(logs: list[Path]) -> None:
    """Refuse, before any work, a log argument that is no file: one line naming it (and
    how many more), exit 1 (a mistyped path is not one log failing among many)."""
    from toolkit.errors import LogReadError

    bad = [p for p in logs if not p.is_file()]
    if not bad:
        return
    first = bad[0]
    problem = (
        "is a directory, not an MCAP log (give its logs: DIR/*.mcap)"
        if first.is_dir()
        else "no such log file"
    )
    more = f" ({len(bad) - 1} more log argument(s) are no file either)" if len(bad) > 1 else ""
    raise LogReadError(f"{problem}{more}", path=first)


def _batch_options(*own: Decorator) -> Decorator:
    """The options of a verb that starts from MCAP files and runs logs in parallel: the logs,
    workspace and configuration, then the verb's ``own``, then executor, workers and shards.
    The verb is called with the click context, :class:`BatchArgs` (checked) and its own."""

    def apply(f: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(f)
        def checked(
            ctx: click.Context,
            *,
            logs: tuple[Path, ...],
            workspace: Path,
            config_path: Path | None,
            executor_kind: str,
            scheduler: str | None,
            workers: int | None,
            shard_index: int,
            num_shards: int,
            **own_values: Any,
        ) -> Any:
            from toolkit.batch import Executors

            executors = Executors(
                executor_kind=executor_kind,
                scheduler=scheduler,
                workers=workers,
                shard_index=shard_index,
                num_shards=num_shards,
            )
            _check_executor_options(ctx, executors)
            batch = BatchArgs(list(logs), workspace, config_path, executors)
            return f(ctx, batch, **own_values)

        wrapped: Callable[..., Any] = click.pass_context(checked)
        for option in reversed([*_LOGS_OPTIONS, *own, *_EXECUTOR_OPTIONS]):
            wrapped = option(wrapped)
        return wrapped

    return apply


_LOGS_OPTIONS: list[Decorator] = [
    click.argument(
        "logs", metavar="LOG.mcap...", nargs=-1, required=True, type=click.Path(path_type=Path)
    ),
    click.option(
        "-w",
        "--workspace",
        required=True,
        type=click.Path(file_okay=False, path_type=Path),
        help="Workspace directory (created if missing).",
    ),
    click.option(
        "-c",
        "--config",
        "config_path",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Pipeline configuration (TOML). Default: the workspace's config.toml if it has "
        "one, else the built-in default (pipelines/stanley2005.toml).",
    ),
]


def _least_option(flag: str, help: str, least: int) -> Decorator:
    """A whole-number option at least ``least``, which is also its default (shown)."""
    return click.option(
        flag, type=click.IntRange(min=least), default=least, show_default=True, help=help
    )


_EXECUTOR_OPTIONS: list[Decorator] = [
    click.option(
        "--executor",
        "executor_kind",
        type=click.Choice(["local", "dask"]),
        default="local",
        show_default=True,
        help="local: a process pool on this machine; dask: a Dask cluster (needs --scheduler "
        "and the 'distributed' extra).",
    ),
    click.option("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786."),
    click.option(
        "--workers",
        type=click.IntRange(min=0),
        default=None,
        help="Local worker processes (default: one per CPU; 0 runs in this process, for "
        "debugging).",
    ),
    _least_option("--shard-index", "This job's shard (0-based), for job arrays.", 0),
    _least_option(
        "--num-shards",
        "How many jobs share the logs; each takes every K-th log of the sorted list.",
        1,
    ),
]


def _stage_option(flag: str, name: str, help: str) -> Decorator:
    """``--from`` or ``--to``: a registered stage's name."""
    return click.option(flag, name, type=StageName(), default=None, help=help)


@main.command()
@_batch_options(
    click.option("--overwrite", is_flag=True, help="Re-ingest logs that are already up to date."),
    click.option("--json", "as_json", is_flag=True, help="Print each log's outcome as JSON."),
)
def ingest(ctx: click.Context, batch: BatchArgs, overwrite: bool, as_json: bool) -> None:
    """MCAP logs -> per-sensor Parquet tables under the workspace, several logs in parallel.

    Logs already ingested with the same configuration are skipped (up to date). A log that
    cannot be ingested does not stop the others; each failure is one line on stderr and
    the exit code is 1.
    """
    from toolkit.batch import run_ingest_batch

    _require_log_files(batch.logs)
    summary = run_ingest_batch(
        batch.logs,
        batch.workspace,
        batch.config_path,
        overwrite=overwrite,
        executors=batch.executors,
    )
    if as_json:
        outcomes = [
            {
                "log": str(o.item),
                "status": status_word(o.label),
                "log_id": getattr(o.result, "log_id", None),
                "error": o.reason or None,
            }
            for o in summary.outcomes
        ]
        emit({"stage": "ingest", "logs": outcomes}, ok=summary.ok)
    else:
        click.echo(summary.render(with_reasons=False))
    if summary.ok:
        return
    for outcome in summary.outcomes:
        if outcome.status != "failed":
            continue
        if outcome.detail and debug_on(ctx):
            click.echo(outcome.detail.rstrip("\n"), err=True)
        error_line(f"{outcome.item}: {outcome.reason}")
    ctx.exit(1)


@main.command()
@_batch_options(
    _stage_option("--from", "first", "First stage to run (default: ingest)."),
    _stage_option("--to", "last", "Last stage to run (default: evaluate)."),
    click.option(
        "--overwrite", is_flag=True, help="Redo every stage in range, even if up to date."
    ),
    click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout."),
)
def run(
    ctx: click.Context,
    batch: BatchArgs,
    first: str | None,
    last: str | None,
    overwrite: bool,
    as_json: bool,
) -> None:
    """Every stage, ingest to evaluate, skipping what is up to date; prints where the report is.

    The per-log stages run logs in parallel (as ingest does); a log that fails a stage is
    reported and left out of the later ones. Killed at any moment and run again, it finishes
    with the outputs an uninterrupted run gives.
    """
    from toolkit.errors import WorkspaceError
    from toolkit.pipeline import run_pipeline, stage_range

    try:
        stage_range(first, last)
    except WorkspaceError as exc:
        raise click.UsageError(str(exc), ctx) from None
    _require_log_files(batch.logs)
    from toolkit.progress import say

    # Each stage's line on stdout as it ends (above the bar on a terminal), then the totals:
    # every line once, whether stdout and stderr go to one pipe or not. With --json, stdout
    # is the JSON alone and the lines are progress on stderr (off a terminal).
    summary = run_pipeline(
        batch.logs,
        batch.workspace,
        batch.config_path,
        first=first,
        last=last,
        overwrite=overwrite,
        executors=batch.executors,
        echo=None if as_json else say,
    )
    if as_json:
        emit(summary.to_dict(), ok=summary.ok)
    else:
        click.echo(summary.render(stages=False))
    if summary.ok:
        return
    for report in summary.stages:
        for item, reason in report.failures.items():
            # A workspace stage's one item is the stage itself: named once.
            where = report.stage if item == report.stage else f"{report.stage}: {item}"
            error_line(f"{where}: {reason}")
    ctx.exit(1)

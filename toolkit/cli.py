"""The ``terrain`` command line: parses arguments, calls one stage, maps errors to exit codes.

Exit codes (the contract): 0 on success; 1 on bad input or a failed stage, with one line
``terrain: error: <message>`` on stderr and no traceback unless ``--debug``; 2 on usage
errors (click's own handling). Every verb registered on :data:`main` gets this mapping from
:class:`TerrainGroup`, so a verb only raises :class:`~toolkit.errors.ToolkitError`.

Verbs import their implementation lazily, so ``terrain --help`` stays fast and a verb's
heavy dependencies load only when it runs.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
import threading
import traceback
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from toolkit import __version__
from toolkit.errors import LogReadError, ToolkitError
from toolkit.pools import Terminated, sigterm_as_exit
from toolkit.progress import set_quiet
from toolkit.stages import registry

PROG = "terrain"


class _StageName(click.ParamType):  # type: ignore[type-arg]
    """A registered stage's name (:mod:`toolkit.stages.registry`), checked when parsed."""

    name = "stage"

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        return "[" + "|".join(registry.names()) + "]"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        if value in registry.names():
            return str(value)
        self.fail(f"{value!r} is not a stage: {', '.join(registry.names())}", param, ctx)


_log = logging.getLogger("toolkit")


@dataclass(frozen=True)
class CliOptions:
    """The global options, kept on the click context for every verb."""

    verbose: int = 0
    quiet: bool = False
    debug: bool = False


def _error_line(message: str) -> None:
    """Print one error line to stderr (newlines in the message folded)."""
    one_line = " ".join(str(message).split("\n"))
    click.echo(f"{PROG}: error: {one_line}", err=True)


def _late_global_flag(ctx: click.Context, param: click.Parameter, value: Any) -> None:
    """-v/-q/--debug given after the verb (``terrain ingest -q ...``): same as before it."""
    if not value:
        return
    root = ctx.find_root()
    opts = root.obj if isinstance(root.obj, CliOptions) else CliOptions()
    if param.name == "late_verbose":
        opts = dataclasses.replace(opts, verbose=opts.verbose + int(value))
    elif param.name == "late_quiet":
        opts = dataclasses.replace(opts, quiet=True)
    elif param.name == "late_debug":
        opts = dataclasses.replace(opts, debug=True)
    root.obj = opts
    configure_logging(opts.verbose, opts.quiet, opts.debug)
    set_quiet(opts.quiet)


def _global_flags() -> list[click.Option]:
    """The global flags, as options every verb also accepts (where users type them)."""

    def flag(decls: list[str], **kind: Any) -> click.Option:
        return click.Option(
            decls,
            expose_value=False,
            is_eager=True,
            callback=_late_global_flag,
            help="As before the verb.",
            **kind,
        )

    return [
        flag(["-v", "--verbose", "late_verbose"], count=True),
        flag(["-q", "--quiet", "late_quiet"], is_flag=True),
        flag(["--debug", "late_debug"], is_flag=True),
    ]


class TerrainGroup(click.Group):
    """A click group that maps the toolkit's errors to exit codes for all its commands, and
    lets every command take the global flags after its name too."""

    def add_command(self, cmd: click.Command, name: str | None = None) -> None:
        cmd.params.extend(_global_flags())
        super().add_command(cmd, name)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.Abort):
            raise  # usage errors (exit 2), explicit exits, Ctrl-C: click handles them
        except Terminated:
            _error_line("stopped (SIGTERM)")  # said here, not in the signal handler
            raise
        except ToolkitError as exc:
            if _debug(ctx):
                traceback.print_exc(file=sys.stderr)
            _error_line(str(exc))
            ctx.exit(1)
        except Exception as exc:
            if _debug(ctx):
                traceback.print_exc(file=sys.stderr)
                _error_line(f"internal error: {type(exc).__name__}: {exc}")
            else:
                _error_line(
                    f"internal error: {type(exc).__name__}: {exc} "
                    f"(run '{PROG} --debug ...' for the traceback)"
                )
            ctx.exit(1)


class StagesGroup(TerrainGroup):
    """The ``terrain`` group: its own commands, and one command per registered stage
    (:mod:`toolkit.stages.registry`), made when first asked for."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self.commands, *registry.names()})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None and cmd_name in registry.names():
            command = _stage_command(cmd_name)
            self.add_command(command)
        return command


def _debug(ctx: click.Context) -> bool:
    opts = ctx.find_object(CliOptions)
    return bool(opts and opts.debug)


class _OneLineFormatter(logging.Formatter):
    """``terrain: warning: [logger] message`` on one line (tracebacks only with --debug)."""

    def __init__(self, show_traces: bool) -> None:
        super().__init__()
        self.show_traces = show_traces

    def format(self, record: logging.LogRecord) -> str:
        message = " ".join(record.getMessage().splitlines())
        line = f"{PROG}: {record.levelname.lower()}: [{record.name}] {message}"
        if self.show_traces and record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


def configure_logging(verbose: int, quiet: bool, debug: bool) -> None:
    """Route log records to stderr: WARNING by default, INFO with -v, DEBUG with -vv."""
    if quiet:
        level = logging.ERROR
    elif verbose >= 2:
        level = logging.DEBUG
    elif verbose == 1:
        level = logging.INFO
    else:
        level = logging.WARNING
    root = logging.getLogger()
    for handler in [h for h in root.handlers if getattr(h, "_terrain", False)]:
        root.removeHandler(handler)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_OneLineFormatter(show_traces=debug))
    handler._terrain = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(level)
    logging.captureWarnings(True)


@click.group(cls=StagesGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars.")
@click.option("--debug", is_flag=True, help="Show tracebacks on errors.")
@click.version_option(__version__, "--version", prog_name=PROG, message="%(prog)s %(version)s")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: bool, debug: bool) -> None:
    """Self-supervised terrain roughness estimation (Stavens & Thrun, 2006) over MCAP logs."""
    ctx.obj = CliOptions(verbose=verbose, quiet=quiet, debug=debug)
    configure_logging(verbose, quiet, debug)
    set_quiet(quiet)
    _stop_on_sigterm(ctx)


def _stop_on_sigterm(ctx: click.Context) -> None:
    """SIGTERM ends the command as Ctrl-C does, every ``with`` unwound (pool workers
    stopped, temporary files removed, locks released); restored when the command ends."""
    if threading.current_thread() is threading.main_thread():  # (not in a test's thread)
        ctx.with_resource(sigterm_as_exit())


def _require_file(path: Path, error: type[ToolkitError] = ToolkitError) -> None:
    """Bad input, not a usage error: a missing input file exits 1 with one line."""
    if not path.exists():
        raise error("no such file", path=path)
    if not path.is_file():
        raise error("not a file", path=path)


@main.command()
@click.argument("out", metavar="OUT.mcap", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--profile",
    type=click.Choice(["sample", "race", "calibration"]),
    default="sample",
    show_default=True,
    help="sample: about a minute dense with rough features; race: a realistic desert "
    "stretch (default 8 km); calibration: one obstacle type driven over at five speeds.",
)
@click.option(
    "--distance-m",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    help="Route length in metres (default: the profile's).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    default=None,
    help="Processes casting laser rays (default: one per core, at most 3; 0 on one core). "
    "The log is the same whatever the number.",
)
@click.option(
    "--no-lasers",
    is_flag=True,
    help="Leave the laser scans out: a fast log of the same drive and IMU, for judging "
    "the vehicle's physics and the shock labels.",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT.mcap.")
def sim(
    out: Path,
    profile: str,
    distance_m: float | None,
    seed: int,
    workers: int | None,
    no_lasers: bool,
    overwrite: bool,
) -> None:
    """Write a synthetic race log with ground truth to OUT.mcap."""
    if not out.parent.is_dir():
        raise ToolkitError("output directory does not exist", path=out.parent)
    # Like export and viz: a log already there (a recorded one, the bundled sample) is only
    # replaced when asked.
    if out.exists() and not overwrite:
        raise ToolkitError("already exists; pass --overwrite to replace it", path=out)
    from toolkit.workspace import refuse_inside_workspace

    refuse_inside_workspace(out)  # a log written there would pass for one of the workspace's
    from toolkit.sim.simulate import simulate

    result = simulate(
        out,
        profile=profile,
        distance_m=distance_m,
        seed=seed,
        show_progress=True,  # a bar on a terminal, a heartbeat off it, nothing with -q
        workers=workers,
        lasers=not no_lasers,
    )
    click.echo(result.summary())


@main.command()
@click.argument("log", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@click.option(
    "--full", is_flag=True, help="Read every record with CRC checks, even when an index exists."
)
def info(log: Path, as_json: bool, full: bool) -> None:
    """Topics, types, counts, rates, duration and problems found in LOG.mcap."""
    _require_file(log, LogReadError)
    from toolkit.mcapio.info import render_table, scan_log

    log_info = scan_log(log, full=full)
    if as_json:
        click.echo(json.dumps(log_info.to_dict(), indent=2, sort_keys=False))
    else:
        click.echo(render_table(log_info))


@main.group(cls=TerrainGroup)
def config() -> None:
    """Pipeline configurations: write a starting one from a log."""


@config.command("init")
@click.argument("log", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option(
    "--out",
    "out_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Write the configuration to this file (default: stdout).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
def config_init(log: Path, out_path: Path | None, overwrite: bool) -> None:
    """A starting configuration for LOG.mcap's robot, written from the log itself.

    Topics are matched to roles by message type, then by name; mounts come from /tf_static
    when the log has it. Every guess is commented, every missing role said, and the head
    of the file says which stages the log can feed. The output loads as it is; read the
    lines marked CHECK, then pass it to ingest with -c.
    """
    _require_file(log, LogReadError)
    if out_path is not None:
        # Checked before the log is read: a configuration someone edited is not replaced
        # by a fresh guess unless asked.
        if out_path.exists() and not overwrite:
            raise ToolkitError("already exists; pass --overwrite to replace it", path=out_path)
        if not out_path.parent.is_dir():
            raise ToolkitError("output directory does not exist", path=out_path.parent)
    from toolkit.config_init import init_config

    text = init_config(log)
    if out_path is None:
        click.echo(text, nl=False)
        return
    from toolkit.atomic import atomic_write_text

    atomic_write_text(out_path, text)
    click.echo(f"wrote {out_path}", err=True)


def _logs_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The logs, workspace and configuration of the verbs that start from MCAP files."""
    f = click.option(
        "-c",
        "--config",
        "config_path",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Pipeline configuration (TOML). Default: the workspace's config.toml if it has "
        "one, else the built-in default (pipelines/stanley2005.toml).",
    )(f)
    f = click.option(
        "-w",
        "--workspace",
        required=True,
        type=click.Path(file_okay=False, path_type=Path),
        help="Workspace directory (created if missing).",
    )(f)
    return click.argument(
        "logs", metavar="LOG.mcap...", nargs=-1, required=True, type=click.Path(path_type=Path)
    )(f)


def _check_executor_options(
    ctx: click.Context, executor_kind: str, scheduler: str | None, shard_index: int, num_shards: int
) -> None:
    """Usage errors among the executor and shard options (exit 2)."""
    if executor_kind == "dask" and not scheduler:
        raise click.UsageError("--executor dask needs --scheduler ADDR", ctx)
    if executor_kind != "dask" and scheduler is not None:
        raise click.UsageError("--scheduler applies only with --executor dask", ctx)
    if shard_index >= num_shards:
        raise click.BadParameter(
            f"{shard_index} is not below --num-shards {num_shards}",
            ctx,
            param_hint="'--shard-index'",
        )


def _executor_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The options of every verb that runs logs in parallel: executor, workers, shards."""
    for option in reversed(_EXECUTOR_OPTIONS):
        f = option(f)
    return f


_EXECUTOR_OPTIONS = [
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
    click.option(
        "--shard-index",
        type=click.IntRange(min=0),
        default=0,
        show_default=True,
        help="This job's shard (0-based), for job arrays.",
    ),
    click.option(
        "--num-shards",
        type=click.IntRange(min=1),
        default=1,
        show_default=True,
        help="How many jobs share the logs; each takes every K-th log of the sorted list.",
    ),
]


@main.command()
@_logs_options
@click.option("--overwrite", is_flag=True, help="Re-ingest logs that are already up to date.")
@click.option("--json", "as_json", is_flag=True, help="Print each log's outcome as JSON.")
@_executor_options
@click.pass_context
def ingest(
    ctx: click.Context,
    logs: tuple[Path, ...],
    workspace: Path,
    config_path: Path | None,
    overwrite: bool,
    as_json: bool,
    executor_kind: str,
    scheduler: str | None,
    workers: int | None,
    shard_index: int,
    num_shards: int,
) -> None:
    """MCAP logs -> per-sensor Parquet tables under the workspace, several logs in parallel.

    Logs already ingested with the same configuration are skipped (up to date). A log that
    cannot be ingested does not stop the others; each failure is one line on stderr and
    the exit code is 1.
    """
    _check_executor_options(ctx, executor_kind, scheduler, shard_index, num_shards)
    from toolkit.batch import run_ingest_batch

    summary = run_ingest_batch(
        list(logs),
        workspace,
        config_path,
        overwrite=overwrite,
        executor_kind=executor_kind,
        scheduler=scheduler,
        workers=workers,
        shard_index=shard_index,
        num_shards=num_shards,
    )
    if as_json:
        outcomes = [
            {
                "log": str(o.item),
                "status": o.label,
                "log_id": getattr(o.result, "log_id", None),
                "error": o.reason or None,
            }
            for o in summary.outcomes
        ]
        click.echo(json.dumps({"stage": "ingest", "logs": outcomes}, indent=2))
    else:
        click.echo(summary.render(with_reasons=False))
    if summary.ok:
        return
    for outcome in summary.outcomes:
        if outcome.status != "failed":
            continue
        if outcome.detail and _debug(ctx):
            click.echo(outcome.detail.rstrip("\n"), err=True)
        _error_line(f"{outcome.item}: {outcome.reason}")
    ctx.exit(1)


def _each_log(
    workspace: Path, log_id: str | None, verb: str, overwrite: bool, as_json: bool = False
) -> None:
    """Run a per-log stage on one log or every log of the workspace, under its lock: one
    summary line per log, one error line per failed log (the others still run), a total
    line for several logs, exit 1 when any failed. With ``as_json`` the summary lines are
    one JSON document instead (:func:`_stage_json`); the error lines stay on stderr."""
    from toolkit.manifest import Manifest
    from toolkit.stages.runner import run_stage
    from toolkit.workspace import Workspace

    spec = registry.stage(verb)
    ws = Workspace(workspace)
    cfg = ws.read_config()
    ids = ws.log_ids()
    if log_id is not None:
        ws.require_log(log_id)
        ids = [log_id]
    if not ids:
        click.echo(f"nothing to {verb}: no ingested log in {ws.root} (run `terrain ingest` first)")
        return
    failed: list[str] = []
    done: dict[str, int] = {}
    results: list[dict[str, Any]] = []
    with ws.lock():
        for one in ids:  # one log's failure never stops the others
            try:
                result = run_stage(spec, ws, cfg, log_id=one, overwrite=overwrite)
            except ToolkitError as exc:
                _error_line(f"{one}: {exc}")
                failed.append(one)
                results.append({"log_id": one, "status": "failed", "error": str(exc)})
                continue
            if not as_json:
                click.echo(spec.describe(result))
            done[result.status] = done.get(result.status, 0) + 1
            record = Manifest(ws.log_manifest_path(one)).stage(verb)
            results.append(
                {
                    "log_id": one,
                    "status": result.status,
                    "summary": spec.describe(result),
                    "record": record.to_json() if record is not None else None,
                }
            )
    if as_json:
        click.echo(json.dumps({"stage": verb, "logs": results}, indent=2))
    elif len(ids) > 1 or failed:
        parts = [f"{n} {status.replace('_', ' ')}" for status, n in sorted(done.items())]
        logs = f"{len(ids)} log{'s' if len(ids) != 1 else ''}"
        click.echo(f"{verb}: {logs}: {', '.join(parts + [f'{len(failed)} failed'])}")
    if failed:
        raise click.exceptions.Exit(1)


JSON_HELP = "Print the result as JSON on stdout (each log's status, summary and record)."


def _echo_stage(ws: Any, stage: str, status: str, text: str, as_json: bool) -> None:
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
    click.echo(json.dumps(doc, indent=2))


def _per_log_options() -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """The options every per-log verb takes: -w, --log, --overwrite."""

    def apply(f: Callable[..., Any]) -> Callable[..., Any]:
        f = click.option("--json", "as_json", is_flag=True, help=JSON_HELP)(f)
        f = click.option(
            "--overwrite", is_flag=True, help="Run it again even if it is up to date."
        )(f)
        f = click.option("--log", "log_id", default=None, help="One log id (default: every log).")(
            f
        )
        return click.option(
            "-w",
            "--workspace",
            required=True,
            type=click.Path(file_okay=False, path_type=Path),
            help="Workspace directory (ingested).",
        )(f)

    return apply


_WORKSPACE_OPTION = click.option(
    "-w",
    "--workspace",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Workspace directory (with its training tables).",
)


def _stage_command(name: str) -> click.Command:
    """The command of registered stage ``name``: per log (-w, --log, --overwrite, --json)
    or over the workspace (-w, --overwrite, --json)."""
    line = registry.listed(name)
    if line.scope == "log":

        def per_log(workspace: Path, log_id: str | None, overwrite: bool, as_json: bool) -> None:
            _each_log(workspace, log_id, name, overwrite, as_json)

        command = typing.cast(
            click.Command, _per_log_options()(click.Command(name, callback=per_log, help=line.help))
        )
        command.params.reverse()  # decorating a made command appends: -w first, as elsewhere
        return command

    def over_workspace(workspace: Path, overwrite: bool, as_json: bool) -> None:
        _workspace_stage(name, workspace, overwrite, as_json)

    command = click.Command(name, callback=over_workspace, help=line.help)
    command = click.option("--json", "as_json", is_flag=True, help=JSON_HELP)(command)
    command = click.option(
        "--overwrite", is_flag=True, help="Run it again even if it is up to date."
    )(command)
    command = _WORKSPACE_OPTION(command)
    command.params.reverse()
    return command


def _workspace_stage(name: str, workspace: Path, overwrite: bool, as_json: bool) -> None:
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


@main.command()
@_logs_options
@click.option(
    "--from",
    "first",
    type=_StageName(),
    default=None,
    help="First stage to run (default: ingest).",
)
@click.option(
    "--to",
    "last",
    type=_StageName(),
    default=None,
    help="Last stage to run (default: evaluate).",
)
@click.option("--overwrite", is_flag=True, help="Redo every stage in range, even if up to date.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
@_executor_options
@click.pass_context
def run(
    ctx: click.Context,
    logs: tuple[Path, ...],
    workspace: Path,
    config_path: Path | None,
    first: str | None,
    last: str | None,
    overwrite: bool,
    as_json: bool,
    executor_kind: str,
    scheduler: str | None,
    workers: int | None,
    shard_index: int,
    num_shards: int,
) -> None:
    """Every stage, ingest to evaluate, skipping what is up to date; prints where the report is.

    The per-log stages run logs in parallel (as ingest does); a log that fails a stage is
    reported and left out of the later ones. Killed at any moment and run again, it finishes
    with the outputs an uninterrupted run gives.
    """
    _check_executor_options(ctx, executor_kind, scheduler, shard_index, num_shards)
    from toolkit.pipeline import run_pipeline

    summary = run_pipeline(
        list(logs),
        workspace,
        config_path,
        first=first,
        last=last,
        overwrite=overwrite,
        executor_kind=executor_kind,
        scheduler=scheduler,
        workers=workers,
        shard_index=shard_index,
        num_shards=num_shards,
    )
    click.echo(json.dumps(summary.to_dict(), indent=2) if as_json else summary.render())
    if summary.ok:
        return
    for report in summary.stages:
        for item, reason in report.failures.items():
            # A workspace stage's one item is the stage itself: named once.
            where = report.stage if item == report.stage else f"{report.stage}: {item}"
            _error_line(f"{where}: {reason}")
    ctx.exit(1)


@main.command()
@_WORKSPACE_OPTION
@click.option("--log", "log_id", required=True, help="The log to show (its workspace id).")
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="The MCAP file to write (Foxglove opens it).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def viz(workspace: Path, log_id: str, out_path: Path, overwrite: bool) -> None:
    """A Foxglove view of one log's results: pose, points by predicted roughness, events."""
    from toolkit.publish.viz import run_viz
    from toolkit.workspace import Workspace

    ws = Workspace(workspace).require()
    cfg = ws.read_config()
    # Shared: learn and evaluate cannot replace the scores or the model mid-read.
    with ws.lock(shared=True):
        result = run_viz(ws, log_id, out_path, cfg, overwrite=overwrite)
    click.echo(result.summary())


@main.command()
@_WORKSPACE_OPTION
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="The dataset folder to write (Hugging Face layout, dataset card, croissant.json).",
)
@click.option("--overwrite", is_flag=True, help="Replace an earlier export in that folder.")
def export(workspace: Path, out_dir: Path, overwrite: bool) -> None:
    """The labelled training and test tables as a dataset other teams load (datasets, Croissant)."""
    from toolkit.publish.export import run_export
    from toolkit.workspace import Workspace

    ws = Workspace(workspace).require()
    cfg = ws.read_config()
    with ws.lock(shared=True):
        result = run_export(ws, out_dir, cfg, overwrite=overwrite)
    click.echo(result.summary())


@main.command("logs")
@_WORKSPACE_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def logs_(workspace: Path, as_json: bool) -> None:
    """The workspace's logs: source file, stages done, rows; then tables, learn, evaluate."""
    from toolkit.listing import list_workspace
    from toolkit.workspace import Workspace

    listing = list_workspace(Workspace(workspace))
    click.echo(listing.to_json() if as_json else listing.text())

"""What every ``terrain`` command shares: the program's name, the global flags (before or
after the verb), the mapping of errors to exit codes and one-line log records on stderr."""

from __future__ import annotations

import dataclasses
import logging
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from toolkit.cli.json_out import emit_failure, json_asked
from toolkit.errors import ToolkitError
from toolkit.progress import set_quiet, write_above_bars
from toolkit.stopping import Stopped

PROG = "terrain"


@dataclass(frozen=True)
class CliOptions:
    """The global options, kept on the click context for every verb."""

    verbose: int = 0
    quiet: bool = False
    debug: bool = False


def error_line(message: str) -> None:
    """Print one error line to stderr (newlines in the message folded)."""
    one_line = " ".join(str(message).split("\n"))
    click.echo(f"{PROG}: error: {one_line}", err=True)


def debug_on(ctx: click.Context) -> bool:
    """Whether ``--debug`` was given (tracebacks wanted)."""
    opts = ctx.find_object(CliOptions)
    return bool(opts and opts.debug)


def apply_global_flags(opts: CliOptions) -> None:
    """Log level, trace display and progress bars as the global flags say."""
    configure_logging(opts.verbose, opts.quiet, opts.debug)
    set_quiet(opts.quiet)


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
    apply_global_flags(opts)


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
        # With --json, a verb that fails before printing its own document prints this one
        # (toolkit.cli.json_out); the error line goes to stderr either way.
        as_json = json_asked(ctx.args)
        try:
            return super().invoke(ctx)
        except click.exceptions.ClickException as exc:  # usage errors (exit 2)
            if as_json and not getattr(exc, "json_said", False):
                emit_failure("usage", exc.format_message(), None, exc.exit_code)
                exc.json_said = True  # type: ignore[attr-defined]  # once, nested groups
            raise
        except (click.exceptions.Exit, click.Abort):
            raise  # explicit exits (the verb said its own), click's Ctrl-C
        except Stopped as exc:
            error_line(exc.line)  # said here, not in the signal handler
            exc.said = True
            if as_json:
                emit_failure("stopped", exc.line, None, int(exc.code or 1))
            raise
        except ToolkitError as exc:
            if debug_on(ctx):
                traceback.print_exc(file=sys.stderr)
            error_line(str(exc))
            if as_json:
                emit_failure("input", str(exc), exc.path, 1)
            ctx.exit(1)
        except Exception as exc:
            if debug_on(ctx):
                traceback.print_exc(file=sys.stderr)
                error_line(f"internal error: {type(exc).__name__}: {exc}")
            else:
                error_line(
                    f"internal error: {type(exc).__name__}: {exc} "
                    f"(run '{PROG} --debug ...' for the traceback)"
                )
            if as_json:
                emit_failure("internal", f"{type(exc).__name__}: {exc}", None, 1)
            ctx.exit(1)


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


class _AboveBars(logging.Handler):
    """Each record one line on stderr, written above the progress bars on a terminal: a
    warning is never glued to a bar's line."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            write_above_bars(self.format(record))
        except Exception:  # noqa: BLE001 - logging's contract: a handler never raises
            self.handleError(record)


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
    handler = _AboveBars()
    handler.setFormatter(_OneLineFormatter(show_traces=debug))
    handler._terrain = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(level)
    logging.captureWarnings(True)


Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


def workspace_option(help: str) -> Decorator:
    """The ``-w/--workspace`` option of the verbs that read a workspace, with its help."""
    return click.option(
        "-w",
        "--workspace",
        required=True,
        type=click.Path(file_okay=False, path_type=Path),
        help=help,
    )


WORKSPACE_OPTION = workspace_option("Workspace directory (with its training tables).")

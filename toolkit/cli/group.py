"""The ``terrain`` group itself (:data:`main`): the global flags before the verb, SIGTERM as
Ctrl-C, and the stages' commands next to its own."""

from __future__ import annotations

import click

from toolkit import __version__
from toolkit.cli.base import PROG, CliOptions, TerrainGroup, apply_global_flags
from toolkit.cli.stages import stage_command
from toolkit.pools import exit_without_waiting
from toolkit.stages import registry
from toolkit.stopping import stop_on_signals


class StagesGroup(TerrainGroup):
    """The ``terrain`` group: its own commands, and one command per registered stage
    (:mod:`toolkit.stages.registry`), made when first asked for."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self.commands, *registry.names()})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None and cmd_name in registry.names():
            command = stage_command(cmd_name)
            self.add_command(command)
        return command


@click.group(cls=StagesGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars.")
@click.option("--debug", is_flag=True, help="Show tracebacks on errors.")
@click.version_option(__version__, "--version", prog_name=PROG, message="%(prog)s %(version)s")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: bool, debug: bool) -> None:
    """Self-supervised terrain roughness estimation (Stavens & Thrun, 2006) over MCAP logs."""
    ctx.obj = CliOptions(verbose=verbose, quiet=quiet, debug=debug)
    apply_global_flags(ctx.obj)
    # Ctrl-C and SIGTERM stop the command, every ``with`` unwound (pool workers stopped,
    # temporary files removed, locks released). The launcher (toolkit.launch) has set this
    # up already; a command run in-process (a test's CliRunner) gets it here.
    ctx.with_resource(stop_on_signals())


def entry() -> None:
    """The process's entry point (``terrain``, ``python -m toolkit``): :data:`main`, and,
    when an interrupt stopped a pool mid-task, an exit that does not wait on the pool's
    threads (:func:`toolkit.pools.exit_without_waiting`)."""
    try:
        main()
    except SystemExit as exc:  # click ends every run so, Ctrl-C and SIGTERM included
        exit_without_waiting(exc.code if isinstance(exc.code, int) else 1)
        raise

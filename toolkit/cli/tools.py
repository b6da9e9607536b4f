"""The verbs around the stages: ``sim`` (a synthetic log), ``info`` (what a log holds),
``config init`` (a starting configuration), ``viz`` and ``export`` (a workspace's results for
others) and ``logs`` (what a workspace holds)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import click

from toolkit.cli.base import WORKSPACE_OPTION, TerrainGroup
from toolkit.cli.group import main
from toolkit.cli.json_out import emit, result_doc
from toolkit.errors import LogReadError, ToolkitError

if TYPE_CHECKING:
    from toolkit.config import PipelineConfig
    from toolkit.workspace import Workspace


#: The help of --json on the verbs that write outside a workspace.
JSON_HELP = "Print the result as JSON on stdout (docs/json.md)."


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
    type=click.FloatRange(min=100.0),
    default=None,
    help="Route length in metres, at least 100 (default: the profile's). The log drives "
    "about 90 m less: its first metres settle the suspension, its last 60 m are the "
    "controller's look-ahead; the summary says how far it drove.",
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
@click.option(
    "--lidar",
    is_flag=True,
    help="Add a spinning 3-D lidar (an Ouster OS1-32, 512 x 10 Hz) on the roof, publishing "
    "ouster-ros point clouds on /ouster/points (docs/simulator.md).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT.mcap.")
@click.option("--json", "as_json", is_flag=True, help=JSON_HELP)
def sim(
    out: Path,
    profile: str,
    distance_m: float | None,
    seed: int,
    workers: int | None,
    no_lasers: bool,
    lidar: bool,
    overwrite: bool,
    as_json: bool,
) -> None:
    """Write a synthetic race log with ground truth to OUT.mcap."""
    require_out_parent(out)
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
        lidar=lidar,
    )
    if as_json:
        emit(result_doc(result))
    else:
        click.echo(result.summary())


@main.command()
@click.argument("log", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@click.option(
    "--full", is_flag=True, help="Read every record with CRC checks, even when an index exists."
)
def info(log: Path, as_json: bool, full: bool) -> None:
    """Topics, types, counts, rates, duration and problems found in LOG.mcap, and which
    roles of [topics] each topic's type can play (`config init` chooses among them)."""
    _require_file(log, LogReadError)
    from toolkit.ingestion.roles import roles_accepting
    from toolkit.mcapio.info import render_table, scan_log

    log_info = scan_log(log, full=full)
    roles = {t.topic: roles_accepting(t.message_type, t.layout) for t in log_info.topics}
    if as_json:
        doc = log_info.to_dict()
        for topic in doc["topics"]:
            topic["roles"] = list(roles[topic["topic"]])
        emit(doc)
    else:
        click.echo(render_table(log_info, roles))


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
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print JSON on stdout: the configuration's text, and where it went with --out.",
)
def config_init(log: Path, out_path: Path | None, overwrite: bool, as_json: bool) -> None:
    """A starting configuration for LOG.mcap's robot, written from the log itself.

    Topics are matched to roles by message type, then by name; mounts come from /tf_static
    when the log has it. Every guess is commented, every missing role said, and the head
    of the file says which stages the log can feed. The output loads as it is; read the
    lines marked CHECK, then pass it to ingest with -c.
    """
    _require_file(log, LogReadError)
    if out_path is not None:
        from toolkit.workspace import refuse_inside_workspace

        # Like viz and sim: never a workspace's own files (its config.toml, a manifest),
        # --overwrite or not.
        refuse_inside_workspace(out_path)
        # Checked before the log is read: a configuration someone edited is not replaced
        # by a fresh guess unless asked.
        if out_path.exists() and not overwrite:
            raise ToolkitError("already exists; pass --overwrite to replace it", path=out_path)
        if not out_path.parent.is_dir():
            raise ToolkitError("output directory does not exist", path=out_path.parent)
    from toolkit.config_init import init_config

    text = init_config(log)
    if out_path is not None:
        from toolkit.atomic import atomic_write_text

        atomic_write_text(out_path, text)
        click.echo(f"wrote {out_path}", err=True)
    if as_json:
        emit({"log": str(log), "out": None if out_path is None else str(out_path), "toml": text})
    elif out_path is None:
        click.echo(text, nl=False)


def require_out_parent(out: Path) -> None:
    """Every verb that writes outside a workspace (sim, viz, export) writes into a folder
    that exists: a mistyped path is said in one line, never made into a tree of folders."""
    parent = out.absolute().parent
    if not parent.is_dir():
        raise ToolkitError("output directory does not exist", path=parent)


def _out_option(name: str, help: str, **kind: bool) -> Callable[[Any], Any]:
    """``--out``, where ``viz`` and ``export`` write (``kind``: a file or a folder)."""
    return click.option(
        "--out", name, required=True, type=click.Path(path_type=Path, **kind), help=help
    )


class _Summarised(Protocol):
    def summary(self) -> str: ...


def _publish(
    workspace: Path, write: Callable[[Workspace, PipelineConfig], _Summarised], as_json: bool
) -> None:
    """Write a workspace's results for others (``write``) and print its summary (or with
    ``as_json`` its document). Under the shared lock: learn and evaluate cannot replace the
    scores or the model mid-read."""
    from toolkit.workspace import Workspace

    ws = Workspace(workspace).require()
    cfg = ws.read_config()
    with ws.lock(shared=True):
        result = write(ws, cfg)
    if as_json:
        emit(result_doc(result))
    else:
        click.echo(result.summary())


@main.command()
@WORKSPACE_OPTION
@click.option("--log", "log_id", required=True, help="The log to show (its workspace id).")
@_out_option("out_path", "The MCAP file to write (Foxglove opens it).", dir_okay=False)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--json", "as_json", is_flag=True, help=JSON_HELP)
def viz(workspace: Path, log_id: str, out_path: Path, overwrite: bool, as_json: bool) -> None:
    """A Foxglove view of one log's results: pose, points by predicted roughness, events."""
    from toolkit.publish.viz import run_viz

    require_out_parent(out_path)
    _publish(
        workspace,
        lambda ws, cfg: run_viz(ws, log_id, out_path, cfg, overwrite=overwrite),
        as_json,
    )


@main.command()
@WORKSPACE_OPTION
@_out_option(
    "out_dir",
    "The dataset folder to write (Hugging Face layout, dataset card, croissant.json).",
    file_okay=False,
)
@click.option("--overwrite", is_flag=True, help="Replace an earlier export in that folder.")
@click.option("--json", "as_json", is_flag=True, help=JSON_HELP)
def export(workspace: Path, out_dir: Path, overwrite: bool, as_json: bool) -> None:
    """The labelled training and test tables as a dataset other teams load (datasets, Croissant)."""
    from toolkit.publish.export import run_export

    require_out_parent(out_dir)
    _publish(workspace, lambda ws, cfg: run_export(ws, out_dir, cfg, overwrite=overwrite), as_json)


@main.command("logs")
@WORKSPACE_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def logs_(workspace: Path, as_json: bool) -> None:
    """The workspace's logs: source file, stages done, rows; then tables, learn, evaluate."""
    from toolkit.listing import list_workspace
    from toolkit.workspace import Workspace

    listing = list_workspace(Workspace(workspace))
    if as_json:
        emit(listing.to_dict())
    else:
        click.echo(listing.text())

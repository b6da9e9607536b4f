"""Every path of a workspace, each file name spelled once.

::

    WS/config.toml                   the configuration in force
    WS/manifest.json                 stages that span logs (tables, learn, evaluate)
    WS/.lock                         one process at a time (shared by ingests and shards)
    WS/logs/<log_id>/                a log's current generation (:mod:`toolkit.generations`)
        manifest.json                its per-log stages (ingest, pose, project, label)
        <table>.parquet              imu, gps, heading, wheels, laser, pose, points, events, ...
        tf_static.json, mcap_metadata.json, fig5_shock_speed.{csv,png}
    WS/tables/events.parquet, WS/tables/event_points.parquet
    WS/model.json
    WS/report/index.html, scores.parquet, summary.json, figures

A stage names what it reads and writes by *layout name* (``"pose"``, ``"tf_static"``,
``"model"``); :meth:`LogFiles.path` and :meth:`WorkspaceLayout.path` turn a name into a path.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, overload

from toolkit.errors import WorkspaceError

#: A per-log file that is not ``<name>.parquet``, by layout name.
_LOG_FILE_NAMES: dict[str, str] = {
    "manifest": "manifest.json",
    "tf_static": "tf_static.json",
    "mcap_metadata": "mcap_metadata.json",
    "fig5_csv": "fig5_shock_speed.csv",
    "fig5_png": "fig5_shock_speed.png",
}


def log_file_name(name: str) -> str:
    """The file name of a per-log layout name: ``tf_static`` -> ``tf_static.json``, a
    table ``pose`` -> ``pose.parquet``."""
    return _LOG_FILE_NAMES.get(name, f"{name}.parquet")


@dataclass(frozen=True)
class LogFiles:
    """The files of one log's directory: its current generation (``ws.log(id)``) or a new
    one a stage is writing (``LogFiles(gen.path)``)."""

    dir: Path

    def path(self, name: str) -> Path:
        """The file of layout name ``name`` (:func:`log_file_name`)."""
        return self.dir / log_file_name(name)

    def table(self, name: str) -> Path:
        """``<dir>/<name>.parquet``: a table ingest or a stage wrote."""
        return self.dir / f"{name}.parquet"

    @property
    def manifest(self) -> Path:
        return self.path("manifest")

    @property
    def tf_static(self) -> Path:
        return self.path("tf_static")

    @property
    def mcap_metadata(self) -> Path:
        return self.path("mcap_metadata")

    @property
    def imu(self) -> Path:
        return self.table("imu")

    @property
    def gps(self) -> Path:
        return self.table("gps")

    @property
    def heading(self) -> Path:
        return self.table("heading")

    @property
    def wheels(self) -> Path:
        return self.table("wheels")

    @property
    def laser(self) -> Path:
        return self.table("laser")

    @property
    def lidar(self) -> Path:
        return self.table("lidar")

    @property
    def truth_pose(self) -> Path:
        return self.table("truth_pose")

    @property
    def truth_features(self) -> Path:
        return self.table("truth_features")

    @property
    def pose(self) -> Path:
        return self.table("pose")

    @property
    def points(self) -> Path:
        return self.table("points")

    @property
    def events(self) -> Path:
        return self.table("events")

    @property
    def fig5_csv(self) -> Path:
        return self.path("fig5_csv")

    @property
    def fig5_png(self) -> Path:
        return self.path("fig5_png")


#: A workspace-level file by layout name, relative to the root.
_WORKSPACE_FILES: dict[str, str] = {
    "config": "config.toml",
    "manifest": "manifest.json",
    "lock": ".lock",
    "events_table": "tables/events.parquet",
    "event_points_table": "tables/event_points.parquet",
    "model": "model.json",
    "scores": "report/scores.parquet",
    "summary": "report/summary.json",
    "index": "report/index.html",
    "online_scores": "online/scores.parquet",
    "online_steps": "online/steps.parquet",
    "online_summary": "online/summary.json",
    "online_state": "online/state.json",
    # Hidden, as work in progress is: a replay stopped part-way leaves it, the next run
    # resumes from it and removes it once the outputs are written.
    "online_checkpoint": "online/.checkpoint.npz",
}


def workspace_file_name(name: str) -> str:
    """The file name of a workspace-level layout name: ``model`` -> ``model.json``."""
    return Path(_WORKSPACE_FILES[name]).name


class _File:
    """A workspace-level file as a read-only attribute: ``ws.<attr>`` is
    ``ws.path(name)`` (:meth:`WorkspaceLayout.path`); ``doc`` is the attribute's docstring."""

    def __init__(self, name: str, doc: str) -> None:
        self.name = name
        self.__doc__ = doc

    @overload
    def __get__(self, layout: None, owner: type[WorkspaceLayout]) -> _File: ...
    @overload
    def __get__(self, layout: WorkspaceLayout, owner: type[WorkspaceLayout]) -> Path: ...
    def __get__(self, layout: WorkspaceLayout | None, owner: type[WorkspaceLayout]) -> _File | Path:
        return self if layout is None else layout.path(self.name)

    def __set__(self, layout: WorkspaceLayout, value: object) -> None:
        raise AttributeError(f"{self.name}: a workspace's paths are not set")


class WorkspaceLayout:
    """The paths of a workspace rooted at ``root`` (nothing is read or made here)."""

    CONFIG_NAME: ClassVar[str] = _WORKSPACE_FILES["config"]
    MANIFEST_NAME: ClassVar[str] = _WORKSPACE_FILES["manifest"]
    LOCK_NAME: ClassVar[str] = _WORKSPACE_FILES["lock"]

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def path(self, name: str) -> Path:
        """The workspace-level file of layout name ``name`` (``model``, ``events_table``...)."""
        return self.root / _WORKSPACE_FILES[name]

    config_path = _File("config", "``WS/config.toml``: the configuration in force.")
    manifest_path = _File("manifest", "``WS/manifest.json``: records of the stages that span logs.")
    lock_path = _File("lock", "``WS/.lock``.")
    model_path = _File("model", "``WS/model.json``: the learned model.")

    @property
    def logs_dir(self) -> Path:
        """``WS/logs``."""
        return self.root / "logs"

    def log_dir(self, log_id: str) -> Path:
        """``WS/logs/<log_id>``. A log id never starts with a dot: those names are the
        generations' hidden directories and locks (:mod:`toolkit.generations`), which a
        stage must never take for a log."""
        if not log_id or "/" in log_id or "\\" in log_id or log_id.startswith("."):
            raise WorkspaceError(f"invalid log id {log_id!r}", path=self.root)
        return self.logs_dir / log_id

    def log(self, log_id: str) -> LogFiles:
        """The files of one log (``ws.log(id).pose``)."""
        return LogFiles(self.log_dir(log_id))

    def log_table(self, log_id: str, table: str) -> Path:
        """``WS/logs/<log_id>/<table>.parquet`` (imu, gps, pose, points, events, ...)."""
        return self.log(log_id).table(table)

    def log_manifest_path(self, log_id: str) -> Path:
        """``WS/logs/<log_id>/manifest.json``."""
        return self.log(log_id).manifest

    @property
    def tables_dir(self) -> Path:
        """``WS/tables``."""
        return self.events_table.parent

    events_table = _File("events_table", "``WS/tables/events.parquet`` (schema ``tables_events``).")
    event_points_table = _File("event_points_table", "``WS/tables/event_points.parquet``.")

    @property
    def report_dir(self) -> Path:
        """``WS/report``."""
        return self.scores_table.parent

    scores_table = _File("scores", "``WS/report/scores.parquet``.")
    summary_path = _File("summary", "``WS/report/summary.json``.")
    index_path = _File("index", "``WS/report/index.html``: the report's page.")


__all__ = ["LogFiles", "WorkspaceLayout", "log_file_name", "workspace_file_name"]

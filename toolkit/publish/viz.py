"""``terrain viz``: one log's results as an MCAP file Foxglove opens. The pipeline's results
are tables; a person understands them best by watching the drive. Not a pipeline stage: a
command over a finished workspace, reading a consistent snapshot of the log and changing
nothing of it. The manual (topics, colours, how it is made) is ``docs/viz.md``."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from toolkit import __version__
from toolkit.atomic import fsync_dir, fsync_file, temp_path_beside
from toolkit.config import PipelineConfig
from toolkit.errors import StageError
from toolkit.publish.emit import write_mcap
from toolkit.publish.scene import (
    CLOUD_PERIOD_NS,
    DESCRIPTIONS,
    MAX_CLOUD_POINTS,
    TF_RATE_HZ,
    TOPIC_EVENTS,
    TOPIC_GPS,
    TOPIC_POINTS,
    TOPIC_TF,
    TOPIC_TRUTH,
    CloudSettings,
    Scene,
    read_scene,
)
from toolkit.workspace import Workspace, refuse_inside_workspace

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VizResult:
    """What :func:`run_viz` wrote: messages per topic and what they hold."""

    log_id: str
    out_path: Path
    #: ``/tf`` messages (one transform each).
    transforms: int
    #: ``/points`` messages, the points they hold, and the rows of ``points.parquet`` read.
    clouds: int
    cloud_points: int
    points_read: int
    #: ``/events`` messages (one box each), the rough ones, and those with a score.
    events: int
    rough_events: int
    scored_events: int
    #: Cloud points coloured by a score (on a scored event's stretch).
    coloured_points: int
    #: ``/gps`` messages, and the rows left out for having no fix.
    gps_fixes: int
    gps_without_fix: int
    #: ``/truth/path`` messages (0 or 1) and the vertices of its line.
    truth_paths: int
    truth_vertices: int
    bytes_written: int
    seconds: float
    warnings: tuple[str, ...] = ()

    @property
    def topics(self) -> dict[str, int]:
        """Messages per topic written (topics without data are not in the file)."""
        counts = {
            TOPIC_TF: self.transforms,
            TOPIC_POINTS: self.clouds,
            TOPIC_EVENTS: self.events,
            TOPIC_GPS: self.gps_fixes,
            TOPIC_TRUTH: self.truth_paths,
        }
        return {topic: n for topic, n in counts.items() if n}

    def summary(self) -> str:
        """One line for people: where, what per topic, how big, how long."""
        parts = [f"/tf {self.transforms}"]
        if self.clouds:
            parts.append(
                f"/points {self.clouds} clouds, {self.cloud_points} of {self.points_read} "
                f"points ({self.coloured_points} coloured by score)"
            )
        if self.events:
            parts.append(
                f"/events {self.events} boxes ({self.rough_events} rough, "
                f"{self.scored_events} scored)"
            )
        if self.gps_fixes or self.gps_without_fix:
            parts.append(
                f"/gps {self.gps_fixes} fixes ({self.gps_without_fix} rows without a fix left out)"
            )
        if self.truth_paths:
            parts.append(f"/truth/path {self.truth_vertices} vertices")
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return (
            f"{self.log_id}: view written to {self.out_path} ({'; '.join(parts)}), "
            f"{self.bytes_written / 1e6:.1f} MB in {self.seconds:.1f} s"
        )


def run_viz(
    workspace: Workspace,
    log_id: str,
    out_path: Path,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    cloud_period_ns: int = CLOUD_PERIOD_NS,
    max_cloud_points: int = MAX_CLOUD_POINTS,
) -> VizResult:
    """Write the view of one log to ``out_path`` (``docs/viz.md``). An existing
    ``out_path`` is refused unless ``overwrite``; a log the workspace does not have, or
    without a pose, is one StageError line naming it."""
    start = time.perf_counter()
    out_path = Path(out_path)
    if cloud_period_ns <= 0 or max_cloud_points <= 0:
        raise ValueError("cloud_period_ns and max_cloud_points must be positive")
    workspace.require_log(log_id)
    _refuse_existing(out_path, overwrite)
    # A generation opened and discarded: a consistent snapshot of the log's files under its
    # lock (a stage committing meanwhile cannot mix two versions of the log into the view).
    with workspace.change_log(log_id) as gen:
        return _write_view(
            workspace,
            log_id,
            gen.path,
            out_path,
            config,
            overwrite=overwrite,
            clouds=CloudSettings(cloud_period_ns, max_cloud_points),
            start=start,
        )


def _refuse_existing(out_path: Path, overwrite: bool) -> None:
    refuse_inside_workspace(out_path)  # never over a workspace's own files
    if out_path.is_dir():
        raise StageError("is a directory; give the view's file name", path=out_path)
    if out_path.exists() and not overwrite:
        raise StageError("already exists; pass --overwrite to replace it", path=out_path)


def _view_metadata(
    log_id: str, scene: Scene, config: PipelineConfig, clouds: CloudSettings
) -> dict[str, str]:
    """The file's ``terrain.viz`` metadata record: the log, the toolkit, the world frame,
    every input's sha256, the numbers behind the colours, and what each topic shows."""
    events = scene.events
    return {
        "log_id": log_id,
        "toolkit_version": __version__,
        "world_frame": scene.pose_metadata.get("frame_id", ""),
        "enu_origin": scene.pose_metadata.get("enu_origin", ""),
        "inputs_sha256": json.dumps(scene.inputs_sha256, sort_keys=True),
        "mu": "" if scene.mu is None else repr(scene.mu),
        "r_combined_low": "" if events.r_low is None else repr(events.r_low),
        "rough_threshold_g_per_mph": repr(config.label.rough_threshold_g_per_mph),
        "cloud_period_ns": str(clouds.period_ns),
        "max_cloud_points": str(clouds.max_points),
        "tf_rate_hz": repr(TF_RATE_HZ),
        **{f"topic {t}": d for t, d in DESCRIPTIONS.items()},
    }


def _write_view(
    workspace: Workspace,
    log_id: str,
    log_dir: Path,
    out_path: Path,
    config: PipelineConfig,
    *,
    overwrite: bool,
    clouds: CloudSettings,
    start: float,
) -> VizResult:
    warnings: list[str] = []
    scene = read_scene(workspace, log_id, log_dir, config, warnings)
    metadata = _view_metadata(log_id, scene, config, clouds)
    tmp = temp_path_beside(out_path)
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        counts = write_mcap(tmp, scene, config, metadata, clouds)
        fsync_file(tmp)
        # Checked again just before the rename: the file may have appeared while we wrote.
        _refuse_existing(out_path, overwrite)
        os.replace(tmp, out_path)
    except BaseException as exc:
        with contextlib.suppress(OSError):  # never written, or not even its directory
            tmp.unlink()
        if isinstance(exc, OSError):  # the file system's (the inputs' are ToolkitErrors)
            raise StageError(f"cannot write the view: {exc.strerror or exc}", out_path) from exc
        raise
    fsync_dir(out_path.parent)
    for warning in warnings:
        _log.warning("%s: %s", log_id, warning)
    return VizResult(
        log_id=log_id,
        out_path=out_path,
        bytes_written=out_path.stat().st_size,
        seconds=time.perf_counter() - start,
        warnings=tuple(warnings),
        **counts,
    )


__all__ = ["VizResult", "run_viz"]

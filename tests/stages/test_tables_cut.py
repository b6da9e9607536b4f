"""A cloud kept near the tyres' paths (``[project] keep = "near_path"``) is checked with what
the paths are drawn from: a change that moves them redoes the cut or is refused (issue 36,
point 5: a new track over a cloud cut around the old paths left tables and learn exiting 0
with half the points under the tyres missing)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest

from tests.stages.crafted import write_table
from tests.stages.test_tables import craft_events
from toolkit.config import PipelineConfig, config_hash, default_config
from toolkit.errors import StageError
from toolkit.manifest import file_sha256
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.stages.tables import SPEC as TABLES
from toolkit.tableio import read_table, read_table_metadata
from toolkit.tyre_paths import META_CUT_AROUND, META_KEPT_WITHIN_M, PATH_INPUTS, PATH_SETTINGS
from toolkit.workspace import Workspace

#: Scans projected (of the sample's 25,000): seconds of driving, a second of projection.
SCANS = 3_000
#: The sample vehicle's track and a new one, a metre wider: each tyre's path moves 50 cm,
#: beyond the cut's 30 cm radius and 20 cm margin.
OLD_TRACK_M, NEW_TRACK_M = 1.65, 2.65


def _near_path(track_m: float) -> PipelineConfig:
    """The default configuration keeping the points near the tyres' paths, at ``track_m``."""
    cfg = default_config()
    assert cfg.vehicle.track_m == OLD_TRACK_M
    return dataclasses.replace(
        cfg,
        project=dataclasses.replace(cfg.project, keep="near_path"),
        vehicle=dataclasses.replace(cfg.vehicle, track_m=track_m),
    )


@pytest.fixture()
def cut(sample_projected: tuple[Path, str], tmp_path: Path) -> tuple[Workspace, str]:
    """A copy of the sample with its first :data:`SCANS` scans kept, its events crafted and
    its cloud cut around the tyres' paths at the old track."""
    root, log_id = sample_projected
    shutil.copytree(root, tmp_path / "ws", symlinks=True)
    ws = Workspace(tmp_path / "ws")
    path = ws.log_table(log_id, "laser")
    meta = read_table_metadata(path)
    laser = read_table(path, "laser").slice(0, SCANS)
    write_table(
        path,
        laser,
        "laser",
        source_sha256=meta["source_sha256"],
        config_hash=meta["config_hash"],
    )
    craft_events(ws, log_id)
    result = run_stage(PROJECT, ws, _near_path(OLD_TRACK_M), log_id=log_id, overwrite=True)
    assert result.points > 0 and result.far_from_path > 0
    return ws, log_id


def test_a_new_track_over_a_cloud_cut_around_the_old_paths_is_refused(
    cut: tuple[Workspace, str],
) -> None:
    """The cloud was cut around the tyres' paths at the old track; tables run alone (as
    ``terrain tables`` or ``terrain run --from tables``) with a new one would match its
    paths against a strip that no longer holds them: refused in one line naming the file,
    what moved and how to redo the cut. Nothing is written."""
    ws, log_id = cut
    with pytest.raises(StageError) as err:
        run_stage(TABLES, ws, _near_path(NEW_TRACK_M))
    message = str(err.value)
    assert "\n" not in message
    assert str(ws.log_table(log_id, "points")) in message
    assert f"vehicle.track_m = {OLD_TRACK_M} when cut, {NEW_TRACK_M} now" in message
    assert f"terrain project -w {ws.root} --log {log_id} --overwrite" in message
    assert not ws.event_points_table.exists()
    # At the track it was cut for, the same cloud makes the tables.
    assert run_stage(TABLES, ws, _near_path(OLD_TRACK_M)).status == "written"


def test_the_cut_cloud_records_what_its_paths_were_drawn_from(
    cut: tuple[Workspace, str],
) -> None:
    """The cut cloud's metadata says how near it keeps the points and what the paths were
    drawn from (the track and the pose's sha256); project redoes the cut when the track
    changes (its key holds the track), and tables then take the new cloud."""
    ws, log_id = cut
    points = ws.log_table(log_id, "points")
    pose_sha = file_sha256(ws.log_table(log_id, "pose"))
    meta = read_table_metadata(points)
    assert float(meta[META_KEPT_WITHIN_M]) == pytest.approx(0.5)
    assert json.loads(meta[META_CUT_AROUND]) == {
        "settings": {"vehicle.track_m": OLD_TRACK_M},
        "inputs": {"pose": pose_sha},
    }
    # Pose's key holds the whole [vehicle] (its mounts and lever arms): a project run
    # alone on the pose of the old track is refused (tests/stages/test_runner.py), so the
    # pose is made again first (stamped with its new key), and the labels after it.
    run_stage(POSE, ws, _near_path(NEW_TRACK_M), log_id=log_id)
    again = run_stage(PROJECT, ws, _near_path(NEW_TRACK_M), log_id=log_id)
    assert again.status == "projected"
    meta = read_table_metadata(points)
    assert json.loads(meta[META_CUT_AROUND])["settings"] == {"vehicle.track_m": NEW_TRACK_M}
    run_stage(LABEL, ws, _near_path(NEW_TRACK_M), log_id=log_id)
    assert run_stage(TABLES, ws, _near_path(NEW_TRACK_M)).status == "written"


def test_projects_key_holds_what_the_paths_are_drawn_from_when_it_cuts() -> None:
    """Cutting, project's up-to-date key holds the settings the paths are drawn from and it
    needs their inputs (one definition: :data:`~toolkit.tyre_paths.PATH_SETTINGS`,
    :data:`~toolkit.tyre_paths.PATH_INPUTS`); the key is the one it was before they were
    named (its whole [vehicle] held the track already), so no cut is redone for it."""
    cfg = _near_path(OLD_TRACK_M)
    hashed = PROJECT.hashed_sections(cfg)
    assert set(PATH_SETTINGS) <= set(hashed)
    assert set(PATH_INPUTS) <= {need.name for need in PROJECT.needs}
    assert set(PATH_INPUTS) <= {need.name for need in TABLES.needs}
    before = ("vehicle", "project", "model.wheel_window_radius_m")
    assert PROJECT.config_hash(cfg) == config_hash(cfg, before)
    assert PROJECT.config_hash(cfg) != PROJECT.config_hash(_near_path(NEW_TRACK_M))

"""The workspace's layout: every path, each file name spelled once."""

from __future__ import annotations

from pathlib import Path

import pytest

from toolkit.errors import WorkspaceError
from toolkit.workspace import Workspace


def test_workspace_paths_follow_the_contract(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    assert ws.config_path == tmp_path / "config.toml"
    assert ws.log_manifest_path("L") == tmp_path / "logs" / "L" / "manifest.json"
    assert ws.log_table("L", "points") == tmp_path / "logs" / "L" / "points.parquet"
    assert ws.events_table == tmp_path / "tables" / "events.parquet"
    assert ws.event_points_table == tmp_path / "tables" / "event_points.parquet"
    assert ws.model_path == tmp_path / "model.json"
    assert ws.scores_table == tmp_path / "report" / "scores.parquet"
    assert ws.summary_path == tmp_path / "report" / "summary.json"
    assert ws.manifest().path == tmp_path / "manifest.json"
    for bad in ("", "..", "a/b", ".a.lock", ".a.host-1-abc.gen", "a\\b"):
        with pytest.raises(WorkspaceError, match="invalid log id"):
            ws.log_dir(bad)


def test_a_log_s_files_by_layout_name(tmp_path: Path) -> None:
    files = Workspace(tmp_path).log("L")
    assert files.dir == tmp_path / "logs" / "L"
    assert files.pose == files.path("pose") == files.dir / "pose.parquet"
    assert files.tf_static == files.dir / "tf_static.json"
    assert files.fig5_png == files.dir / "fig5_shock_speed.png"
    assert files.manifest == files.dir / "manifest.json"


#: The files of a workspace, each to be spelled in toolkit/layout.py alone.
WORKSPACE_FILES = (
    "config.toml",
    "manifest.json",
    "pose.parquet",
    "points.parquet",
    "events.parquet",
    "imu.parquet",
    "gps.parquet",
    "heading.parquet",
    "wheels.parquet",
    "laser.parquet",
    "truth_pose.parquet",
    "truth_features.parquet",
    "tf_static.json",
    "mcap_metadata.json",
    "fig5_shock_speed.csv",
    "fig5_shock_speed.png",
    "event_points.parquet",
    "model.json",
    "scores.parquet",
    "summary.json",
    "index.html",
)


def test_every_workspace_file_name_is_spelled_once_in_the_layout() -> None:
    package = Path(__file__).resolve().parents[1] / "toolkit"
    spelled: dict[str, list[str]] = {}
    for module in package.rglob("*.py"):
        text = module.read_text(encoding="utf-8")
        for name in WORKSPACE_FILES:
            if f'"{name}"' in text or f"'{name}'" in text:
                spelled.setdefault(name, []).append(str(module.relative_to(package)))
    elsewhere = {n: m for n, m in spelled.items() if m != ["layout.py"]}
    assert elsewhere == {}

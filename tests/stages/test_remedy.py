"""A log that cannot feed a stage is said to, with why, never told to run that stage:
Clearpath's Husky has no scanner and a 30 Hz IMU (too slow for the shock band)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import DATA_DIR
from toolkit.config import load_config
from toolkit.errors import StageError
from toolkit.layout import LogFiles
from toolkit.publish.viz import run_viz
from toolkit.stages.ingest import ingest_log
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import remedy, run_stage
from toolkit.stages.tables import SPEC as TABLES
from toolkit.workspace import Workspace

HUSKY_LOG = DATA_DIR / "real-logs" / "husky-gps-imu-odom.mcap"
HUSKY_CONFIG = Path(__file__).resolve().parents[2] / "pipelines" / "husky.toml"


def test_a_log_that_cannot_feed_a_stage_is_told_why_not_to_run_it(tmp_path: Path) -> None:
    config = load_config(HUSKY_CONFIG)
    ws = Workspace(tmp_path / "ws")
    log_id = ingest_log(HUSKY_LOG, ws, config).log_id
    run_stage(POSE, ws, config, log_id=log_id)
    files = ws.log(log_id)
    assert remedy("project", files, config).startswith(
        "this log cannot feed project: projection needs a scanner, and this log has none"
    )
    label = remedy("label", files, config)
    assert label.startswith("this log cannot feed label: IMU rate 30.01")
    assert "cannot carry the shock band" in label and str(files.imu) not in label
    assert remedy("pose", files, config) == "run `terrain pose` on it"  # no check: it could
    with pytest.raises(StageError, match="cannot carry the shock band"):
        run_stage(LABEL, ws, config, log_id=log_id)
    with pytest.raises(StageError) as err:
        run_stage(TABLES, ws, config)
    message = str(err.value)
    assert "no log has finished events, points and pose" in message
    assert "this log cannot feed label" in message and "run `terrain" not in message
    out = tmp_path / "view.mcap"
    result = run_viz(ws, log_id, out, config)
    assert out.is_file()
    said = " ".join(result.warnings)
    assert "no /points (this log cannot feed project" in said
    assert "no /events (this log cannot feed label" in said
    assert "run `terrain" not in said


def test_a_log_that_could_is_told_to_run_the_stage(sample_projected: tuple[Path, str]) -> None:
    """The sample before label: told to run it (its IMU samples at 100 Hz)."""
    from toolkit.config import default_config

    root, log_id = sample_projected
    assert remedy("label", LogFiles(root / "logs" / log_id), default_config()) == (
        "run `terrain label` on it"
    )

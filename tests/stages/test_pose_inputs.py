"""Pose refuses, in one line naming the file, inputs that are not what ingest wrote."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.stages.crafted import adopt_edits
from toolkit.config import default_config
from toolkit.errors import StageError, WorkspaceError
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"


@pytest.fixture(scope="module")
def ingested(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, str]:
    ws = Workspace(tmp_path_factory.mktemp("inputs") / "ws")
    return ws, ingest_log(SAMPLE_LOG, ws, default_config()).log_id


def _copy(ingested: tuple[Workspace, str], to: Path) -> tuple[Workspace, str]:
    ws, log_id = ingested
    shutil.copytree(ws.root, to, symlinks=True)
    return Workspace(to), log_id


@pytest.mark.parametrize(
    "text", ["{not json", '{"terrain_sim": {"origin": "x", "gps_dropouts_ns": "[[1]]"}}', "[]"]
)
def test_edited_simulator_metadata_is_refused(
    ingested: tuple[Workspace, str], tmp_path: Path, text: str
) -> None:
    ws, log_id = _copy(ingested, tmp_path / "ws")
    path = ws.log_dir(log_id) / "mcap_metadata.json"
    path.write_text(text)
    with pytest.raises(WorkspaceError, match="not the file the last finished ingest wrote") as e:
        run_stage(POSE, ws, default_config(), log_id=log_id)
    assert str(path) in str(e.value)
    # Even recorded as ingest's own output (as if ingest had written it), it is a StageError
    # naming the file, never an internal error.
    adopt_edits(ws.log_dir(log_id))
    with pytest.raises(StageError, match="not the simulator metadata ingest writes") as e2:
        run_stage(POSE, ws, default_config(), log_id=log_id)
    assert "mcap_metadata.json" in str(e2.value)
    assert not (ws.log_dir(log_id) / "pose.parquet").exists()

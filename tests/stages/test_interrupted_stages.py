"""A stage interrupted while writing leaves no half-written file, for every stage's output.

Each stage runs once to completion, then again with ``--overwrite`` while its table writer is
made to fail part-way (Ctrl-C on the second piece written, or the disk filling up). Afterwards
no file of the interrupted run is left (no hidden partial file) and every output under its
own name is byte for byte the one the complete run wrote.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pytest

from toolkit.config import PipelineConfig, default_config
from toolkit.errors import WorkspaceError
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import TableWriter
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"

Stage = Callable[[Workspace, str, PipelineConfig], object]


def _ingest(ws: Workspace, log_id: str, config: PipelineConfig) -> object:
    return ingest_log(SAMPLE_LOG, ws, config, overwrite=True)


def _pose(ws: Workspace, log_id: str, config: PipelineConfig) -> object:
    return run_stage(POSE, ws, config, log_id=log_id, overwrite=True)


STAGES: dict[str, Stage] = {"ingest": _ingest, "pose": _pose}

FAULTS: dict[str, tuple[type[BaseException], BaseException]] = {
    "ctrl_c": (KeyboardInterrupt, KeyboardInterrupt()),
    "disk_full": (WorkspaceError, OSError(28, "No space left on device")),
}


@pytest.fixture(scope="module")
def posed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, str]:
    ws = Workspace(tmp_path_factory.mktemp("interrupted") / "ws")
    result = ingest_log(SAMPLE_LOG, ws, default_config())
    run_stage(POSE, ws, default_config(), log_id=result.log_id)
    return ws, result.log_id


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if p.is_file()}


@pytest.mark.parametrize("fault", sorted(FAULTS))
@pytest.mark.parametrize("stage", sorted(STAGES))
def test_interrupted_stage_leaves_no_partial_file(
    posed: tuple[Workspace, str],
    stage: str,
    fault: str,
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    # Each case on its own copy: an interrupted ingest leaves its log not current (its
    # record removed), which a later case must not inherit.
    shutil.copytree(posed[0].root, tmp_path / "ws", symlinks=True)
    ws, log_id = Workspace(tmp_path / "ws"), posed[1]
    log_dir = ws.log_dir(log_id)
    before = {k: v for k, v in _files(log_dir).items() if k.endswith(".parquet")}
    assert {"imu.parquet", "laser.parquet", "pose.parquet"} <= before.keys()
    expected, error = FAULTS[fault]
    real = TableWriter.write
    calls = {"n": 0}

    def failing_write(self: TableWriter, table: pa.Table) -> None:
        calls["n"] += 1
        if calls["n"] == 2:
            if isinstance(error, OSError):  # as pyarrow's writer would meet it
                raise WorkspaceError(f"cannot write table: {error}", self.path) from error
            raise error
        real(self, table)

    monkeypatch.setattr(TableWriter, "write", failing_write)
    with pytest.raises(expected):
        STAGES[stage](ws, log_id, default_config())
    assert calls["n"] == 2
    after = _files(log_dir)
    assert [name for name in after if name.startswith(".")] == []
    assert {k: v for k, v in after.items() if k.endswith(".parquet")} == before

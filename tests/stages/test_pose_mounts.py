"""Pose with sensor mounts from /tf_static or the configuration, and a turned IMU.

The sample log's IMU is mounted along base_link's axes. Re-expressing its samples as an IMU
turned by a mount rotation R would read them (``v_imu = R^T v_base``) and declaring that mount
must give the same pose: the stage turns the samples back with the mount it finds.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from scipy.spatial.transform import Rotation

from toolkit.config import PipelineConfig, default_config
from toolkit.errors import StageError
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table, read_table_metadata
from toolkit.workspace import Workspace

from .crafted import adopt_edits, write_table

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"

#: A mount no one would guess: the Husky's IMU (roll 90 deg, yaw -90 deg).
TURNED_RPY = (np.pi / 2, 0.0, -np.pi / 2)


@pytest.fixture(scope="module")
def posed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, str, pa.Table]:
    ws = Workspace(tmp_path_factory.mktemp("mounts") / "ws")
    log_id = ingest_log(SAMPLE_LOG, ws, default_config()).log_id
    run_stage(POSE, ws, default_config(), log_id=log_id)
    return ws, log_id, read_table(ws.log_table(log_id, "pose"), "pose")


def _copy(ws: Workspace, log_id: str, to: Path) -> Workspace:
    shutil.copytree(ws.root, to, symlinks=True)
    copy = Workspace(to)
    for name in ("pose.parquet",):
        (copy.log_dir(log_id) / name).unlink()
    return copy


def _turn_imu(ws: Workspace, log_id: str, base_from_imu: np.ndarray) -> None:
    path = ws.log_table(log_id, "imu")
    imu = read_table(path, "imu")
    meta = read_table_metadata(path)
    columns = {name: imu.column(name) for name in imu.column_names}
    for quantity in ("accel", "gyro"):
        v = np.stack([imu.column(f"{quantity}_{a}").to_numpy() for a in "xyz"], axis=1)
        v_imu = v @ base_from_imu  # rows: (R^T v)^T = v^T R
        for k, a in enumerate("xyz"):
            columns[f"{quantity}_{a}"] = pa.array(v_imu[:, k])
    write_table(
        path,
        pa.table(columns),
        "imu",
        source_sha256=meta["source_sha256"],
        config_hash=meta["config_hash"],
    )


def _set_imu_mount(ws: Workspace, log_id: str, rpy: tuple[float, float, float]) -> None:
    path = ws.log_dir(log_id) / "tf_static.json"
    tf = json.loads(path.read_text())
    roll, pitch, yaw = rpy
    quat = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat().tolist()
    for t in tf["transforms"]:
        if t["child_frame"] == "imu_link":
            t["rotation_xyzw"] = quat
    path.write_text(json.dumps(tf))
    adopt_edits(path.parent)


def _max_difference(a: pa.Table, b: pa.Table) -> tuple[float, float]:
    pos = max(float(np.max(np.abs(a.column(c).to_numpy() - b.column(c).to_numpy()))) for c in "xyz")
    att = max(
        float(np.max(np.abs(a.column(c).to_numpy() - b.column(c).to_numpy())))
        for c in ("roll", "pitch", "yaw")
    )
    return pos, att


def test_turned_imu_declared_in_tf_static_gives_the_same_pose(
    posed: tuple[Workspace, str, pa.Table], tmp_path: Path
) -> None:
    ws, log_id, reference = posed
    copy = _copy(ws, log_id, tmp_path / "ws")
    base_from_imu = Rotation.from_euler("ZYX", TURNED_RPY[::-1]).as_matrix()
    _turn_imu(copy, log_id, base_from_imu)
    _set_imu_mount(copy, log_id, TURNED_RPY)
    result = run_stage(POSE, copy, default_config(), log_id=log_id)
    assert result.warnings == ()
    pos, att = _max_difference(read_table(copy.log_table(log_id, "pose"), "pose"), reference)
    assert pos < 1e-3 and att < 1e-5, (pos, att)


def test_turned_imu_without_tf_static_uses_the_config_and_warns(
    posed: tuple[Workspace, str, pa.Table], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ws, log_id, reference = posed
    copy = _copy(ws, log_id, tmp_path / "ws")
    tf = json.loads((copy.log_dir(log_id) / "tf_static.json").read_text())
    mounts = {t["child_frame"]: t["translation_m"] for t in tf["transforms"]}
    (copy.log_dir(log_id) / "tf_static.json").unlink()
    adopt_edits(copy.log_dir(log_id))
    base_from_imu = Rotation.from_euler("ZYX", TURNED_RPY[::-1]).as_matrix()
    _turn_imu(copy, log_id, base_from_imu)
    default = default_config()
    config: PipelineConfig = dataclasses.replace(
        default,
        vehicle=dataclasses.replace(
            default.vehicle,
            imu_position_m=tuple(mounts["imu_link"]),
            imu_orientation_rad=TURNED_RPY,
            gps_antenna_position_m=tuple(mounts["gps_antenna"]),
        ),
    )
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        result = run_stage(POSE, copy, config, log_id=log_id)
    assert len(result.warnings) == 2 and all("no /tf_static" in w for w in result.warnings)
    said = [r.getMessage() for r in caplog.records]
    assert all(any(w in line for line in said) for w in result.warnings)
    pos, att = _max_difference(read_table(copy.log_table(log_id, "pose"), "pose"), reference)
    assert pos < 1e-3 and att < 1e-5, (pos, att)


def test_a_wrongly_declared_mount_changes_the_pose(
    posed: tuple[Workspace, str, pa.Table], tmp_path: Path
) -> None:
    """The check above can fail: the same turned samples with the mount left level."""
    ws, log_id, reference = posed
    copy = _copy(ws, log_id, tmp_path / "ws")
    _turn_imu(copy, log_id, Rotation.from_euler("ZYX", TURNED_RPY[::-1]).as_matrix())
    try:
        run_stage(POSE, copy, default_config(), log_id=log_id)
    except StageError:  # a filter that diverges also shows the mount matters
        return
    pos, _ = _max_difference(read_table(copy.log_table(log_id, "pose"), "pose"), reference)
    assert pos > 1.0


def test_truth_is_written_in_the_pose_frame(posed: tuple[Workspace, str, pa.Table]) -> None:
    """truth_pose and pose share the frame (metadata and values): read side by side, their
    differences are the filter's errors, which the manifest's accuracy reports."""
    ws, log_id, pose = posed
    truth_path = ws.log_table(log_id, "truth_pose")
    truth_meta = read_table_metadata(truth_path)
    pose_meta = read_table_metadata(ws.log_table(log_id, "pose"))
    assert truth_meta["frame_id"] == pose_meta["frame_id"] == "enu_agreeing_fix"
    assert json.loads(truth_meta["enu_origin"]) == json.loads(pose_meta["enu_origin"])
    truth = read_table(truth_path, "truth_pose")
    t = pose.column("t_ns").to_numpy()
    tt = truth.column("t_ns").to_numpy()
    inside = (t >= tt[0]) & (t <= tt[-1])
    ex, ey = (
        pose.column(c).to_numpy()[inside] - np.interp(t[inside], tt, truth.column(c).to_numpy())
        for c in "xy"
    )
    rmse = float(np.sqrt(np.mean(ex**2 + ey**2)))
    accuracy = ws.manifest(log_id).read()["pose_accuracy"]
    assert rmse < 0.3
    assert rmse == pytest.approx(accuracy["horizontal_rmse_m"], abs=1e-4)  # stored to 0.1 mm


def test_pose_refuses_inputs_no_finished_ingest_wrote(
    posed: tuple[Workspace, str, pa.Table], tmp_path: Path
) -> None:
    """A table edited (or left by an interrupted ingest) is not what the finished ingest
    recorded: pose refuses it, naming the file, rather than pose a log nobody ingested."""
    from toolkit import tableio
    from toolkit.errors import WorkspaceError

    ws, log_id, _ = posed
    copy = _copy(ws, log_id, tmp_path / "ws")
    path = copy.log_table(log_id, "wheels")
    meta = read_table_metadata(path)
    tableio.write_table(
        path,
        read_table(path, "wheels").slice(0, 100),
        "wheels",
        source_sha256=meta["source_sha256"],
        config_hash=meta["config_hash"],
    )
    with pytest.raises(WorkspaceError, match="wheels.parquet: not the file the last finished"):
        run_stage(POSE, copy, default_config(), log_id=log_id)

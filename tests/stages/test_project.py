"""The project stage: laser scans + pose -> world points (paper sect. 3)."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tests.stages.crafted import write_table
from toolkit.config import default_config
from toolkit.errors import StageError
from toolkit.geometry.mounts import frame_mounts
from toolkit.geometry.rotations import euler_to_rot
from toolkit.manifest import file_sha256
from toolkit.model.projection import Counts, PreparedBatch
from toolkit.stages import project as project_module
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.project_scans import LASER_COLUMNS, PoseStream, ScanBatch, project_batch
from toolkit.stages.runner import run_stage
from toolkit.tableio import (
    from_storage,
    iter_table_batches,
    load_table_schema,
    read_table,
    read_table_metadata,
    to_storage,
)
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"


@pytest.fixture()
def posed_copy(sample_projected: tuple[Path, str], tmp_path: Path) -> tuple[Workspace, str]:
    """A private copy of the shared sample workspace (ingested, posed, projected)."""
    root, log_id = sample_projected
    shutil.copytree(root, tmp_path / "ws", symlinks=True)
    return Workspace(tmp_path / "ws"), log_id


@pytest.fixture(scope="module")
def projected(sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """The sample projected again in a private copy, for the stage's own result."""
    root, log_id = sample_projected
    copy = tmp_path_factory.mktemp("projected") / "ws"
    shutil.copytree(root, copy, symlinks=True)
    ws = Workspace(copy)
    return ws, log_id, run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)


def test_every_return_is_a_point_or_a_counted_reject(projected) -> None:  # type: ignore[no-untyped-def]
    ws, log_id, result = projected
    laser = read_table(ws.log_table(log_id, "laser"), "laser")
    ranges = pc.list_flatten(laser.column("ranges")).to_numpy(zero_copy_only=False)
    assert result.points + sum(result.rejects.values()) == ranges.size
    assert result.rejects["no_return"] == int((~np.isfinite(ranges)).sum()) > 0
    assert result.scans == laser.num_rows
    points = read_table(ws.log_table(log_id, "points"), "points")
    assert points.num_rows == result.points
    # The pose's frame travels with the points.
    meta = read_table_metadata(ws.log_table(log_id, "points"))
    assert meta["frame_id"] == read_table_metadata(ws.log_table(log_id, "pose"))["frame_id"]
    # Each point at its beam's own time; scans of a laser 1/75 s apart.
    inc = float(laser.column("time_increment")[0].as_py())
    beam = points.column("beam").to_numpy()
    dt = points.column("t_ns").to_numpy() - points.column("scan_t_ns").to_numpy()
    np.testing.assert_allclose(dt, beam * inc * 1e9, atol=1.0)
    scan_dt = points.column("scan_dt_s").to_numpy()
    assert np.isnan(scan_dt).sum() <= 181 * 5  # each laser's first scan only
    assert np.nanmedian(scan_dt) == pytest.approx(1 / 75, rel=1e-3)
    # A second run finds everything up to date and does nothing.
    again = run_stage(PROJECT, ws, default_config(), log_id=log_id)
    assert again.status == "up_to_date" and again.points == result.points


def test_the_cloud_is_written_as_a_bulk_table(projected) -> None:  # type: ignore[no-untyped-def]
    """The cloud's coordinates and rates are whole millimetres (1e-6 rad/s) delta-encoded,
    its range byte-stream-split, all under zstd, its times delta-encoded and its laser column
    codes into the topic names (what makes writing it fast and its file small; see
    tableio.bulk_options and toolkit.fixed_point)."""
    ws, log_id, _ = projected
    path = ws.log_table(log_id, "points")
    row_group = pq.ParquetFile(path).metadata.row_group(0)
    by_name = {row_group.column(i).path_in_schema: row_group.column(i) for i in range(11)}
    for name in ("x", "y", "z", "roll_rate", "pitch_rate"):
        assert by_name[name].physical_type == "INT32"
        assert "DELTA_BINARY_PACKED" in by_name[name].encodings
        assert by_name[name].compression == "ZSTD"
    assert "BYTE_STREAM_SPLIT" in by_name["range"].encodings
    for name in ("t_ns", "scan_t_ns"):  # times: delta-encoded, 13 % smaller files
        assert "DELTA_BINARY_PACKED" in by_name[name].encodings
        assert "BYTE_STREAM_SPLIT" not in by_name[name].encodings
    # Min/max statistics on what points are selected by (time, laser, place) alone.
    with_statistics = {name for name, column in by_name.items() if column.is_stats_set}
    assert with_statistics == {"t_ns", "scan_t_ns", "laser", "x", "y"}
    assert by_name["x"].statistics.min <= by_name["x"].statistics.max
    lasers = read_table(path, "points", columns=["laser"]).column("laser")
    assert pa.types.is_dictionary(lasers.type)
    assert set(lasers.cast(pa.string()).unique().to_pylist()) == set(_laser_topics(ws, log_id))


def _laser_topics(ws: Workspace, log_id: str) -> list[str]:
    laser = read_table(ws.log_table(log_id, "laser"), "laser", columns=["laser"])
    return [str(v) for v in laser.column("laser").unique().to_pylist()]


def _laser_meta(ws: Workspace, log_id: str) -> dict[str, str]:
    meta = read_table_metadata(ws.log_table(log_id, "laser"))
    return {"source_sha256": meta["source_sha256"], "config_hash": meta["config_hash"]}


def test_bad_returns_are_dropped_and_counted_by_reason(posed_copy: tuple[Workspace, str]) -> None:
    ws, log_id = posed_copy
    path = ws.log_table(log_id, "laser")
    laser = read_table(path, "laser").slice(0, 500)
    ranges = [list(r) for r in laser.column("ranges").to_pylist()]
    for r in ranges:
        r[0], r[1], r[2], r[3] = float("inf"), float("-inf"), 1000.0, 0.1  # range_max 80, min 0.5
    laser = laser.set_column(
        laser.schema.get_field_index("ranges"), "ranges", pa.array(ranges, pa.list_(pa.float32()))
    )
    write_table(path, laser, "laser", **_laser_meta(ws, log_id))
    result = run_stage(PROJECT, ws, default_config(), log_id=log_id)
    total = 500 * 181
    assert result.points + sum(result.rejects.values()) == total
    assert result.rejects["out_of_range"] == 2 * 500
    non_finite = int((~np.isfinite(np.array(ranges, dtype=np.float32))).sum())
    assert result.rejects["no_return"] == non_finite >= 2 * 500
    assert any("returns dropped" in w for w in result.warnings)
    points = read_table(ws.log_table(log_id, "points"), "points")
    assert points.column("beam").to_numpy().min() >= 4
    assert np.isfinite(points.column("z").to_numpy()).all()


def test_a_laser_that_is_not_stanleys(posed_copy: tuple[Workspace, str]) -> None:
    """A spinning 360-beam lidar at 10 Hz over 360 deg, flat on a mast 1.2 m above base_link
    and turned 30 deg, every range 5 m: each point, taken back into base_link with the pose
    at its own beam time, is exactly where the beam pointed."""
    ws, log_id = posed_copy
    log_dir = ws.log_dir(log_id)
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    t_pose = pose.column("t_ns").to_numpy()
    n_scans, beams = 40, 360
    t_scan = t_pose[100] + np.arange(n_scans, dtype=np.int64) * 100_000_000
    inc = 0.1 / beams
    table = pa.table(
        {
            "t_ns": pa.array(t_scan, pa.int64()),
            "laser": pa.array(["/velodyne"] * n_scans),
            "angle_min": pa.array(np.full(n_scans, -np.pi, np.float32)),
            "angle_increment": pa.array(np.full(n_scans, 2 * np.pi / beams, np.float32)),
            "time_increment": pa.array(np.full(n_scans, inc, np.float32)),
            "ranges": pa.array([[5.0] * beams] * n_scans, pa.list_(pa.float32())),
            "range_min": pa.array(np.full(n_scans, 0.3, np.float32)),
            "range_max": pa.array(np.full(n_scans, 100.0, np.float32)),
            "frame_id": pa.array(["velodyne"] * n_scans),
        }
    )
    tf = json.loads((log_dir / "tf_static.json").read_text())
    tf["transforms"].append(
        {
            "child_frame": "velodyne",
            "parent_frame": "base_link",
            "rotation_xyzw": Rotation.from_euler("z", 30, degrees=True).as_quat().tolist(),
            "t_ns": int(t_scan[0]),
            "translation_m": [0.5, 0.0, 1.2],
        }
    )
    # Edited as a re-ingest of such a log would have written it.
    (log_dir / "tf_static.json").write_text(json.dumps(tf))
    write_table(ws.log_table(log_id, "laser"), table, "laser", **_laser_meta(ws, log_id))
    # A new tf_static reaches the pose too (the runner refuses a pose made from another):
    # posed again, as `terrain run` would after that re-ingest.
    run_stage(POSE, ws, default_config(), log_id=log_id)
    result = run_stage(PROJECT, ws, default_config(), log_id=log_id)
    assert result.points == n_scans * beams and not any(result.rejects.values())
    points = read_table(ws.log_table(log_id, "points"), "points")
    t = points.column("t_ns").to_numpy()
    beam = points.column("beam").to_numpy()
    np.testing.assert_array_equal(
        t,
        np.repeat(t_scan, beams)
        + np.round(np.tile(np.arange(beams), n_scans) * np.float32(inc) * 1e9).astype(np.int64),
    )
    # Back into base_link with the pose at each point's time (scipy's Slerp, independently).
    ts = (t_pose - t_pose[0]) * 1e-9
    rpy = np.stack([pose.column(c).to_numpy() for c in ("roll", "pitch", "yaw")], axis=1)
    rot = Slerp(ts, Rotation.from_matrix(euler_to_rot(rpy)))((t - t_pose[0]) * 1e-9)
    pos = np.stack(
        [np.interp((t - t_pose[0]) * 1e-9, ts, pose.column(c).to_numpy()) for c in "xyz"], 1
    )
    xyz = np.stack([points.column(c).to_numpy() for c in "xyz"], axis=1)
    theta = -np.pi + beam * np.float32(2 * np.pi / beams) + np.pi / 6
    want = np.c_[0.5 + 5 * np.cos(theta), 5 * np.sin(theta), np.full(theta.size, 1.2)]
    # Stored to the millimetre: each coordinate within half a millimetre of the exact point.
    np.testing.assert_allclose(xyz, rot.apply(want) + pos, rtol=0, atol=0.5e-3 + 1e-6)


def test_a_laser_nobody_mounted_is_dropped_with_a_warning(
    posed_copy: tuple[Workspace, str],
) -> None:
    ws, log_id = posed_copy
    path = ws.log_table(log_id, "laser")
    laser = read_table(path, "laser").slice(0, 100)
    frames = ["laser_9"] * 50 + laser.column("frame_id").to_pylist()[50:]
    laser = laser.set_column(laser.schema.get_field_index("frame_id"), "frame_id", pa.array(frames))
    write_table(path, laser, "laser", **_laser_meta(ws, log_id))
    result = run_stage(PROJECT, ws, default_config(), log_id=log_id)
    # Reasons are checked in order: a no-return of that laser counts as no_return.
    first = np.array(laser.column("ranges").to_pylist()[:50], dtype=np.float32)
    assert result.rejects["no_mount"] == int(np.isfinite(first).sum()) > 40 * 181
    assert any("'laser_9'" in w and "not used" in w for w in result.warnings)


def test_projection_needs_a_pose(posed_copy: tuple[Workspace, str]) -> None:
    ws, log_id = posed_copy
    points = file_sha256(ws.log_table(log_id, "points"))
    ws.log_table(log_id, "pose").unlink()
    with pytest.raises(StageError, match="run `terrain pose` first"):
        run_stage(PROJECT, ws, default_config(), log_id=log_id)
    assert file_sha256(ws.log_table(log_id, "points")) == points  # nothing changed


def test_the_papers_fig4_and_the_z_error_come_with_the_points(projected) -> None:  # type: ignore[no-untyped-def]
    """Fig. 4 (|dz| of two scans of one ground cell against the time between them) and, on
    a simulated log, the z error against the true terrain by laser and range: written beside
    the points, recorded as the stage's outputs, the fit in the manifest and the summary."""
    import csv

    ws, log_id, result = projected
    log_dir = ws.log_dir(log_id)
    record = ws.manifest(log_id).stage("project")
    assert record is not None
    for name in (
        "fig4_z_difference_vs_dt.csv",
        "fig4_z_difference_vs_dt.png",
        "z_error_by_laser_and_range.csv",
        "z_error_by_laser_and_range.png",
    ):
        assert (log_dir / name).stat().st_size > 0 and name in record.output_files
    fig4 = json.loads((log_dir / "manifest.json").read_text())["project"]["fig4"]
    assert fig4["pairs"] > 1_000_000 and fig4["slope_m_per_s"] > 0.0
    assert "Fig. 4 |dz| =" in result.summary()
    with (log_dir / "z_error_by_laser_and_range.csv").open() as f:
        # Each laser's overall row (0 to inf m; the last range bin, 75 m up, is open too).
        rows = [r for r in csv.DictReader(f) if (r["range_lo_m"], r["range_hi_m"]) == ("0", "inf")]
    # With the estimated pose the points sit a few centimetres off the true ground: far more
    # than with the true pose (a few millimetres, the test above), far less than a metre.
    assert len(rows) == 6  # five lasers and "all"
    for r in rows:
        assert 0.01 < float(r["median_abs_m"]) < 0.2, r


def test_a_scan_with_nan_geometry_places_nothing(posed_copy: tuple[Workspace, str]) -> None:
    """NaN angles or time increment: every return of that scan is a counted bad_scan, never
    a NaN point written as a good one."""
    ws, log_id = posed_copy
    path = ws.log_table(log_id, "laser")
    laser = read_table(path, "laser").slice(0, 30)
    for k, column in enumerate(("angle_min", "angle_increment", "time_increment")):
        values = laser.column(column).to_numpy().copy()
        values[10 * k : 10 * k + 3] = np.nan
        laser = laser.set_column(laser.schema.get_field_index(column), column, pa.array(values))
    write_table(path, laser, "laser", **_laser_meta(ws, log_id))
    result = run_stage(PROJECT, ws, default_config(), log_id=log_id)
    assert result.rejects["bad_scan"] == 9 * 181
    points = read_table(ws.log_table(log_id, "points"), "points")
    assert np.isfinite(np.stack([points.column(c).to_numpy() for c in "xyz"])).all()
    assert result.points + sum(result.rejects.values()) == 30 * 181


def test_threads_write_what_one_batch_after_another_would(
    posed_copy: tuple[Workspace, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stage projects batches in a pool of threads and writes them in order: its points
    equal, row for row, projecting the same batches one after another (small batches here,
    so many are in flight at once; the scan_dt_s carried across batches included)."""
    ws, log_id = posed_copy
    monkeypatch.setattr(project_module, "SCAN_BATCH", 150)
    run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    log_dir = ws.log_dir(log_id)
    got = read_table(log_dir / "points.parquet", "points")
    frames = sorted(set(read_table(log_dir / "laser.parquet", "laser")["frame_id"].to_pylist()))
    mounts, _ = frame_mounts(log_dir / "tf_static.json", "base_link", frames)
    poses, counts, previous = PoseStream(log_dir / "pose.parquet"), Counts(), {}
    batches = iter_table_batches(
        log_dir / "laser.parquet", "laser", columns=LASER_COLUMNS, batch_rows=150
    )
    tables = [
        project_batch(ScanBatch.from_record_batch(b), mounts, poses, previous, counts)
        for b in batches
    ]
    assert len(tables) > 3 * project_module.WORKERS
    want = pa.concat_tables(tables).select(got.column_names)
    schema = load_table_schema("points")  # as stored: to the millimetre
    want = from_storage(to_storage(want, schema), schema)
    assert got.num_rows == want.num_rows == counts.points
    # Column by column, NaN equal to NaN (a laser's first scan has no scan_dt_s before it).
    got = got.cast(want.schema)
    for name in want.column_names:
        np.testing.assert_array_equal(got[name].to_numpy(), want[name].to_numpy(), err_msg=name)


def test_a_failing_worker_leaves_the_last_cloud_as_it_was(
    posed_copy: tuple[Workspace, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error while a thread projects a batch reaches the caller as itself, and neither
    a partial points.parquet nor a scratch file is left: the last finished cloud stays."""
    ws, log_id = posed_copy
    run_stage(PROJECT, ws, default_config(), log_id=log_id)
    points = ws.log_dir(log_id) / "points.parquet"
    before = file_sha256(points)
    monkeypatch.setattr(project_module, "SCAN_BATCH", 500)
    real = project_module.project_prepared
    calls = {"n": 0}

    def fails_on_the_fourth(batch: PreparedBatch) -> object:
        calls["n"] += 1
        if calls["n"] == 4:
            raise StageError("injected", path=points)
        return real(batch)

    monkeypatch.setattr(project_module, "project_prepared", fails_on_the_fourth)
    with pytest.raises(StageError, match="injected"):
        run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    assert file_sha256(points) == before
    leftovers = [p.name for p in ws.log_dir(log_id).iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_the_disk_estimate_holds_the_figures_the_sample_projection_wrote(projected) -> None:  # type: ignore[no-untyped-def]
    """Every file the stage wrote beside the cloud (Fig. 4, the z error: PNG and CSV) is in
    the disk estimate: together they take less than FIGURE_BYTES."""
    ws, log_id, _ = projected
    record = ws.manifest(log_id).stage("project")
    figures = [name for name in record.outputs if name != project_module.OUTPUT]
    assert {n.rsplit(".", 1)[1] for n in figures} == {"png", "csv"} and len(figures) == 4
    written = sum(ws.log_dir(log_id).joinpath(name).stat().st_size for name in figures)
    assert 0 < written <= project_module.FIGURE_BYTES


def _tiny_scans(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> tuple[Path, project_module.ProjectSettings, int, Callable[[int], None]]:
    """A laser table of 100 scans of 181 returns (all the disk check reads), the default
    settings, the cloud's estimate (bytes) and a setter of the free space the check sees."""
    from collections import namedtuple

    laser = tmp_path / "laser.parquet"
    ranges = pa.array([[1.0] * 181] * 100, pa.list_(pa.float32()))
    pq.write_table(pa.table({"ranges": ranges}), laser)
    cfg = default_config()
    settings = project_module.ProjectSettings(cfg.project, cfg.vehicle, cfg.topics, cfg.model)
    cloud = int(100 * 181 * project_module.CLOUD_BYTES_PER_RETURN[cfg.project.keep])
    Usage = namedtuple("Usage", "total used free")

    def free(n: int) -> None:
        monkeypatch.setattr(project_module.shutil, "disk_usage", lambda _p: Usage(10**9, 0, n))

    return laser, settings, cloud, free


def test_a_disk_that_holds_the_cloud_but_not_its_figures_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The estimate is the cloud and the figures beside it: a disk with room for the cloud
    alone is refused before anything is written, naming the figures."""
    laser, settings, cloud, free = _tiny_scans(tmp_path, monkeypatch)
    free(cloud + 1000)
    with pytest.raises(StageError, match="with its figures, needs about"):
        project_module._require_disk_for_cloud(laser, settings)
    free(cloud + project_module.FIGURE_BYTES)
    project_module._require_disk_for_cloud(laser, settings)  # room for both: no error


def test_an_old_clouds_room_is_not_counted_free(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Projecting again writes the new cloud aside while the old one stays in the log's
    current generation (a hard link to it in the new one) until the stage commits: both are
    on the disk at once, so the old cloud's size is no room for the new one."""
    laser, settings, cloud, free = _tiny_scans(tmp_path, monkeypatch)
    old = tmp_path / "old-generation-points.parquet"
    old.write_bytes(b"\0" * 200_000)
    os.link(old, tmp_path / project_module.OUTPUT)  # as a new generation holds it
    free(cloud + project_module.FIGURE_BYTES - 1000)
    with pytest.raises(StageError, match="needs about"):
        project_module._require_disk_for_cloud(laser, settings)


def test_a_disk_too_small_for_the_cloud_is_said_before_anything_is_written(
    posed_copy: tuple[Workspace, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The cloud's size is estimated from the scans' returns before projecting: a disk that
    cannot hold it is one line with the size and the setting that keeps less, and nothing is
    written; the estimate is the cloud's size to within a quarter."""
    from collections import namedtuple

    ws, log_id = posed_copy
    points_path = ws.log_table(log_id, "points")
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(
        project_module.shutil, "disk_usage", lambda _p: Usage(10**9, 10**9 - 10**6, 10**6)
    )
    points_path.unlink()  # a first projection
    with pytest.raises(StageError, match=r"needs about 0\.0[34] GB.*keep = \"near_path\""):
        run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    assert not points_path.exists()
    assert not [p.name for p in points_path.parent.iterdir() if p.name.startswith(".points")]
    monkeypatch.undo()
    run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    laser = pq.ParquetFile(ws.log_table(log_id, "laser")).metadata
    leaf = next(
        j for j in range(laser.num_columns) if laser.schema.column(j).path.startswith("ranges")
    )
    returns = sum(laser.row_group(i).column(leaf).num_values for i in range(laser.num_row_groups))
    estimate = returns * project_module.CLOUD_BYTES_PER_RETURN["all"]
    assert 0.75 < points_path.stat().st_size / estimate < 1.25

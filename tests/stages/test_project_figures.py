"""The figures the project stage feeds as it makes the points: the z-error sample."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.analysis.truth_terrain import true_ground
from toolkit.stages import project_figures
from toolkit.workspace import Workspace


def test_the_z_error_sample_is_the_checked_points_own_error(
    sample_projected: tuple[Path, str],
) -> None:
    """The project stage's z-error sample of a batch: of every 64th point, those on a checked
    stretch of road, each with its own laser, range and error against the true terrain (the
    stride, the stretch filter and the three columns stay aligned)."""
    root, log_id = sample_projected
    ws = Workspace(root)
    ground = true_ground(ws.log_dir(log_id))
    assert ground is not None
    table = pq.ParquetFile(ws.log_table(log_id, "points")).read_row_group(0)
    every = 2
    sample = project_figures.z_sample(ground, table, threading.Lock(), every)
    assert sample is not None
    xyz = np.stack([table.column(c).to_numpy() for c in "xyz"], axis=1)
    strided = np.arange(0, table.num_rows, project_figures.Z_ERROR_STRIDE)
    s, d, z = ground.route_coordinates(xyz[strided])
    on = strided[ground.checked_stretch(s, every) >= 0]
    assert 0 < on.size < strided.size
    assert sample.laser.to_pylist() == table.column("laser").take(pa.array(on)).to_pylist()
    np.testing.assert_array_equal(sample.range_m, table.column("range").to_numpy()[on])
    heights, z_sim = ground.height_m(xyz[on])
    np.testing.assert_allclose(sample.z_error_m, z_sim - heights, rtol=0, atol=1e-9)


def _lidar_points(scan_t: list[int], rings: list[int], t: list[int]) -> pa.Table:
    n = len(t)
    return pa.table(
        {
            "t_ns": pa.array(t, pa.int64()),
            "laser": pa.array([f"/l ring {r}" for r in rings]).dictionary_encode(),
            "beam": pa.array(rings, pa.int32()),
            "x": np.arange(n, dtype=float),
            "y": np.zeros(n),
            "z": np.zeros(n),
            "scan_t_ns": pa.array(scan_t, pa.int64()),
            "ring": pa.array(rings, pa.int32()),
        }
    )


def test_a_lidar_batch_is_laid_out_as_scans_of_beams_for_fig4() -> None:
    """A lidar's points come in time order, its rings interleaved; Fig. 4 reads each ring's
    sweep as a laser's scan line: contiguous, in time order, numbered along the line."""
    table = _lidar_points(
        scan_t=[0, 0, 0, 0, 0, 100, 100],
        rings=[1, 0, 1, 0, 1, 0, 1],
        t=[1, 1, 2, 2, 3, 101, 101],
    )
    out = project_figures.lidar_sweeps(table)
    assert out.column("ring").to_pylist() == [0, 0, 1, 1, 1, 0, 1]
    assert out.column("t_ns").to_pylist() == [1, 2, 1, 2, 3, 101, 101]
    assert out.column("beam").to_pylist() == [0, 1, 0, 1, 2, 0, 0]
    assert out.column("x").to_pylist() == [1.0, 3.0, 0.0, 2.0, 4.0, 5.0, 6.0]
    laser_points = table.drop_columns(["ring"])
    assert project_figures.lidar_sweeps(laser_points) is laser_points


def test_a_cloud_cut_between_batches_is_fed_whole() -> None:
    first = _lidar_points([0, 0, 100], [0, 1, 0], [1, 1, 101])
    second = _lidar_points([100, 200], [1, 0], [102, 201])
    fed, pending = project_figures.whole_clouds(None, first)
    assert fed.column("scan_t_ns").to_pylist() == [0, 0]
    assert pending is not None and pending.column("t_ns").to_pylist() == [101]
    fed, pending = project_figures.whole_clouds(pending, second)
    assert fed.column("t_ns").to_pylist() == [101, 102]
    assert pending is not None and pending.column("scan_t_ns").to_pylist() == [200]

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

"""Which points lie near the rear tyres' paths: the near_path cloud keeps all the tables use."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from toolkit.tyre_paths import PATH_STEP_M, NearPath


@pytest.mark.parametrize("spin_rad_per_row", [0.0, 0.3, 1.2], ids=["straight", "turn", "spin"])
def test_every_point_near_a_tyre_is_kept_also_where_the_robot_spins(
    spin_rad_per_row: float,
) -> None:
    """A pose at 2 Hz creeping 5 cm a row while turning up to 1.2 rad a row (a skid-steer
    robot on the spot): every point within the radius of the tyres' exact positions at any
    time between rows is kept with the tables' allowance (radius + PATH_STEP_M); points
    far from both tyres are not."""
    rows, track, radius = 40, 1.0, 0.3
    t = np.arange(rows, dtype=np.int64) * 500_000_000
    yaw = np.arange(rows) * spin_rad_per_row
    xy = np.c_[np.arange(rows) * 0.05, np.zeros(rows)]
    near = NearPath(t, xy, yaw, track, radius + PATH_STEP_M)
    # The tyres' positions every 1/1000 of a row, as the tables would place them at events'
    # ends anywhere between rows (position and yaw linear in time).
    f = np.linspace(0, rows - 1, (rows - 1) * 1000 + 1)
    cx, cy, a = (
        np.interp(f, np.arange(rows), xy[:, 0]),
        np.interp(f, np.arange(rows), xy[:, 1]),
        np.interp(f, np.arange(rows), yaw),
    )
    half = track / 2
    tyres = np.r_[
        np.c_[cx - np.sin(a) * half, cy + np.cos(a) * half],
        np.c_[cx + np.sin(a) * half, cy - np.cos(a) * half],
    ]
    rng = np.random.default_rng(1)
    pts = tyres[rng.integers(0, len(tyres), 20_000)] + rng.uniform(-0.45, 0.45, (20_000, 2))
    dist, _ = cKDTree(tyres).query(pts)
    kept = near.mask(pts[:, 0], pts[:, 1])
    assert kept[dist < radius].all()
    assert not kept[dist > radius + PATH_STEP_M + 0.01].any()

"""The paper's eq. (1) points: the pose interpolated at each return's time."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from toolkit.model.projection import PoseWindow


@pytest.mark.parametrize("turn_rad", [np.pi, 0.03], ids=["large_turns", "small_turns"])
def test_interpolation_on_the_rotation_group_equals_scipys_slerp(turn_rad: float) -> None:
    """PoseWindow.transform rotates by R_i exp(f log(R_i^T R_i+1)), which must be exactly
    scipy's Slerp: for large turns between rows and across yaw = +-pi (Rodrigues'
    trigonometric form), and for the few milliradians between real 100 Hz rows, where it
    takes the Taylor series (up to 0.02 rad: the series' limit is crossed both ways)."""
    rng = np.random.default_rng(4)
    k = 50
    t_ns = np.cumsum(rng.integers(5_000_000, 15_000_000, k)).astype(np.int64)
    steps = np.c_[rng.uniform(-turn_rad, turn_rad, k), rng.normal(0, turn_rad / 10, (k, 2))]
    rot = Rotation.from_euler("ZYX", np.cumsum(steps, axis=0) if turn_rad < 1 else steps)
    window = PoseWindow(t_ns, rng.normal(0, 10, (k, 3)), rot, rng.normal(0, 1, (k, 2)))
    tq = rng.integers(int(t_ns[0]), int(t_ns[-1]), 10_000).astype(np.int64)
    p = rng.normal(0, 5, (tq.size, 3))
    got, rates, ok = window.transform(tq, p.T)
    ts = (t_ns - t_ns[0]) * 1e-9
    tqs = (tq - t_ns[0]) * 1e-9
    want = Slerp(ts, rot)(tqs).apply(p) + np.stack(
        [np.interp(tqs, ts, window.position[:, j]) for j in range(3)], axis=1
    )
    np.testing.assert_allclose(got.T, want, atol=1e-9)
    np.testing.assert_allclose(rates[1], np.interp(tqs, ts, window.rates[:, 1]), atol=1e-12)
    # Rows more than 50 ms apart are a hole in the pose: no point is placed across it.
    assert np.array_equal(
        ok, (np.diff(t_ns)[np.searchsorted(t_ns, tq, side="right") - 1] <= 50_000_000)
    )

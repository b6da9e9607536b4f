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


def test_a_negative_range_is_never_projected_even_under_a_negative_range_min() -> None:
    """A LaserScan claiming ``range_min`` = -5 m lets a range of -2 m through its own bounds:
    placed, it would land behind the laser. It is out of range, whatever range_min says."""
    from toolkit.geometry.mounts import Mount
    from toolkit.model.projection import Scans, prepare_scans, project_points

    t0 = 1_700_000_000_000_000_000
    t_ns = t0 + np.arange(20, dtype=np.int64) * 10_000_000
    window = PoseWindow(t_ns, np.zeros((20, 3)), Rotation.identity(20), np.zeros((20, 2)))
    ranges = np.array([-2.0, -0.0, 0.0, 3.0, -1e-3, 5.0], np.float32)
    scans = Scans(
        t_ns=np.array([t0 + 50_000_000], np.int64),
        laser_code=np.zeros(1, np.int64),
        laser_names=["/laser"],
        frame_code=np.zeros(1, np.int64),
        frame_names=["laser"],
        angle_min=np.zeros(1),
        angle_increment=np.zeros(1),
        time_increment=np.zeros(1),
        range_min=np.array([-5.0]),
        range_max=np.array([80.0]),
        scan=np.zeros(ranges.size, np.int64),
        beam=np.arange(ranges.size, dtype=np.int64),
        range_m=ranges,
    )
    mount = Mount.from_rpy("laser", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], "test")
    prepared = prepare_scans(scans, {"laser": mount}, {}, lambda lo, hi: window)
    chunks, counts = project_points(prepared)
    x = np.concatenate([c["x"] for c in chunks])
    got = np.concatenate([c["range"] for c in chunks])
    assert counts.rejects["out_of_range"] == 2  # -2 and -1e-3
    np.testing.assert_array_equal(got, [-0.0, 0.0, 3.0, 5.0])  # zero is no distance behind
    assert (x >= 0).all()  # nothing placed behind the laser

"""The tables stage's streamed pose: its yaw unwrapped batch by batch."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.stages.tables_points import RunningUnwrap


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_running_unwrap_is_np_unwrap_of_the_whole_column(seed: int) -> None:
    """The stage unwraps the pose's yaw batch by batch: bit for bit np.unwrap of the whole
    column, for any split (batches of one row, steps of exactly pi, many turns)."""
    rng = np.random.default_rng(seed)
    raw = np.cumsum(rng.normal(0.0, 0.8, 5_000))
    raw[100:110] = np.cumsum(np.full(10, np.pi))  # steps of exactly +pi
    yaw = np.angle(np.exp(1j * raw))  # wrapped to (-pi, pi]
    yaw[200:205] = [np.pi, -np.pi, np.pi, -np.pi, 0.0]
    cuts = np.sort(rng.choice(np.arange(1, yaw.size), size=60, replace=False))
    cuts = np.unique(np.r_[1, 2, cuts])  # batches of one row at the start
    unwrap = RunningUnwrap("yaw")
    parts = [
        unwrap({"yaw": yaw[lo:hi]})["yaw"]
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, yaw.size], strict=True)
    ]
    mine = np.concatenate(parts)
    np.testing.assert_array_equal(mine, np.unwrap(yaw))
    assert np.abs(np.diff(mine)).max() <= np.pi + 1e-12  # steps within pi, to rounding

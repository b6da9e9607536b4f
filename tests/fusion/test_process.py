"""The pose filter's process model: IMU pre-integration and the motion of a state over it."""

from __future__ import annotations

import numpy as np

from toolkit.fusion.process import ImuIncrement, propagate
from toolkit.fusion.state import DIM_X, GRAVITY, POS, VEL


def stationary_increment(T: float, steps: int) -> ImuIncrement:
    """Level and at rest: the accelerometer reads exactly -g (specific force), gyro 0."""
    inc = ImuIncrement(np.zeros(3), np.zeros(3))
    for _ in range(steps):
        inc.add(-GRAVITY, np.zeros(3), T / steps)
    return inc


def test_process_model_level_constant_speed() -> None:
    """Level, 10 m/s east, IMU reading exactly -g: position advances v T, nothing else."""
    x = np.zeros((1, DIM_X))
    x[0, VEL.start] = 10.0
    inc = stationary_increment(0.1, steps=10)
    out = propagate(x, inc)[0]
    np.testing.assert_allclose(out[POS], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[VEL], [10.0, 0.0, 0.0], atol=1e-12)

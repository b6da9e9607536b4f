"""The pose filter's measurement models."""

from __future__ import annotations

import numpy as np

from toolkit.fusion.measurements import wheel_model
from toolkit.fusion.state import DIM_X, SCALE, VEL


def test_wheel_model_reads_the_scale_error() -> None:
    """Level, 10 m/s forward, no rotation: the odometer reads (1 + ks) 10 m/s."""
    x = np.zeros((2, DIM_X))
    x[:, VEL.start] = 10.0
    x[1, SCALE] = 0.004
    z = wheel_model(np.zeros(3), np.zeros(3))(x)
    np.testing.assert_allclose(z[:, 0], [10.0, 10.04], rtol=0, atol=1e-12)

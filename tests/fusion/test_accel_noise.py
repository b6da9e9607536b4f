"""The accelerometer's noise measured on the log, and the process noise it adds in odometry
dead reckoning."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.fusion.accel_noise import AccelNoise, vibration_q
from toolkit.fusion.state import DIM_X, POS, VEL


def test_accel_noise_estimate_is_the_white_noise_density() -> None:
    """White noise of 0.9 m/s^2 per 20 ms sample is a density of ``0.9^2 x 0.02`` (m/s^2)^2
    s, found whichever way the samples are split into windows; a constant (a bias, gravity)
    adds nothing."""
    rng = np.random.default_rng(0)
    period, sigma = 0.02, np.array([0.9, 0.3, 1.5])
    accel = np.array([0.2, -0.1, 9.8]) + rng.normal(0.0, 1.0, (5000, 3)) * sigma
    whole = AccelNoise(accel[:50], period).window(accel[50:])
    split = AccelNoise(accel[:50], period)
    parts = np.concatenate([split.window(accel[a : a + 97]) for a in range(50, 5000, 97)])
    np.testing.assert_allclose(parts, whole, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(whole[-2000:].mean(axis=0), sigma**2 * period, rtol=0.1)


def test_vibration_q_adds_only_the_excess_and_is_a_covariance() -> None:
    rpy = np.array([0.05, -0.1, 2.0])
    none = vibration_q(rpy, np.full(3, 0.02**2), 0.03, 0.1)
    assert not none.any()  # measured below the configured noise: nothing added
    q = vibration_q(rpy, np.array([0.016, 0.002, 0.045]), 0.03, 0.1)
    assert q.shape == (DIM_X, DIM_X) and np.allclose(q, q.T)
    assert np.linalg.eigvalsh(q).min() > -1e-15
    # Its velocity block is the rotated excess times T; the trace is rotation-invariant.
    excess = np.array([0.016, 0.002, 0.045]) - 0.03**2
    assert np.trace(q[VEL, VEL]) == pytest.approx(excess.sum() * 0.1)
    assert np.trace(q[POS, POS]) == pytest.approx(excess.sum() * 0.1**3 / 3.0)

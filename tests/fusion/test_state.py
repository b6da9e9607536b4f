"""The pose filter's state: angle wrapping in residuals and means, and the vectorised
unscented transform against filterpy's."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import unscented_transform as filterpy_unscented_transform

from toolkit.fusion.state import (
    DIM_X,
    YAW,
    angle_mean,
    angle_residual,
    state_mean,
    state_residual,
    unscented_transform,
)
from toolkit.geometry.rotations import wrap_angle


def test_residuals_wrap_angles() -> None:
    a = np.zeros(DIM_X)
    b = np.zeros(DIM_X)
    a[YAW], b[YAW] = np.pi - 0.01, -np.pi + 0.01
    assert np.isclose(state_residual(a, b)[YAW], -0.02)
    assert np.isclose(angle_residual(np.array([-np.pi + 0.01]), np.array([np.pi - 0.01]))[0], 0.02)


def test_means_wrap_angles() -> None:
    sig = np.zeros((3, DIM_X))
    sig[:, YAW] = [np.pi - 0.01, -np.pi + 0.01, np.pi - 0.01]
    wm = np.array([1 / 3, 1 / 3, 1 / 3])
    m = state_mean(sig, wm)
    assert abs(abs(m[YAW]) - (np.pi - 0.01 / 3)) < 1e-9
    z = angle_mean(np.array([[np.pi - 0.02], [-np.pi + 0.02]]), np.array([0.5, 0.5]))
    assert np.isclose(abs(z[0]), np.pi)


def test_vectorised_unscented_transform_equals_filterpys() -> None:
    """Ours runs on all sigma points at once; filterpy's loops. Same numbers."""
    rng = np.random.default_rng(1)
    sigmas = rng.normal(size=(2 * DIM_X + 1, DIM_X))
    sigmas[:, YAW] = wrap_angle(np.pi + 0.1 * rng.normal(size=2 * DIM_X + 1))  # across +-pi
    wm = rng.uniform(0.01, 0.1, 2 * DIM_X + 1)
    wm /= wm.sum()
    wc = wm.copy()
    wc[0] += 0.3
    Q = np.diag(rng.uniform(0.1, 1.0, DIM_X))
    ours = unscented_transform(sigmas, wm, wc, Q, state_mean, state_residual)
    theirs = filterpy_unscented_transform(sigmas, wm, wc, Q, state_mean, state_residual)
    np.testing.assert_allclose(ours[0], theirs[0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(ours[1], theirs[1], rtol=0, atol=1e-14)

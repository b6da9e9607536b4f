"""so3_exp against scipy's rotation vectors, on both sides of its small-angle series.

``Exp(phi) = I + a K + b K^2`` (``K`` the cross-product matrix of ``phi``). Comparing whole
matrices cannot see the series' ``theta^2`` terms near the switch (they change entries by
~1e-17), so the tests read the two coefficients back out of a matrix, where they are exact
to a few ulps: the antisymmetric part is ``a K`` and the symmetric part less ``I`` is
``b K^2``, whose off-diagonal entries ``b phi_i phi_j`` carry no large term to round against.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from toolkit.geometry.rotations import SO3_SERIES_BELOW_RAD, FloatArray, so3_exp, so3_exp_one

AXIS = np.array([0.48, -0.6, 0.64])  # unit length, no zero component


def coefficients(R: FloatArray, phi: FloatArray) -> tuple[float, float]:
    """(a, b) of ``R = I + a K + b K^2`` for the rotation vector ``phi`` (3,)."""
    a = 0.5 * (R[2, 1] - R[1, 2]) / phi[0]  # (a K)[2, 1] = a phi_x
    b = 0.5 * (R[0, 1] + R[1, 0]) / (phi[0] * phi[1])  # (b K^2)[0, 1] = b phi_x phi_y
    return float(a), float(b)


ANGLES_RAD = [
    1e-12,
    1e-8,
    1.2e-8,
    1e-6,
    0.5 * SO3_SERIES_BELOW_RAD,
    SO3_SERIES_BELOW_RAD * (1.0 - 1e-6),
    SO3_SERIES_BELOW_RAD * (1.0 + 1e-6),
    2.0 * SO3_SERIES_BELOW_RAD,
    1e-3,
    0.1,
    1.0,
    3.0,
]


@pytest.mark.parametrize("theta", ANGLES_RAD)
def test_so3_exp_equals_scipy(theta: float) -> None:
    phi = theta * AXIS
    ours = so3_exp(phi)
    theirs = Rotation.from_rotvec(phi).as_matrix()
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-15)
    a, b = coefficients(ours, phi)
    a_ref, b_ref = coefficients(theirs, phi)
    # Near the switch the theta^2 terms are ~1e-9 of a and b: well above these tolerances.
    assert a == pytest.approx(a_ref, rel=1e-13)
    assert b == pytest.approx(b_ref, rel=1e-11)


def test_so3_exp_coefficients_are_continuous_at_the_switch() -> None:
    """Just below (series) and just above (closed form) agree to round-off.

    ``b`` read back from a matrix is good to ~1e-11 here (``b phi_x phi_y`` ~ 1e-9 next to
    ``a phi_z`` ~ 1e-4 in the same entry); the series' ``theta^2 / 24`` term is 4e-10.
    """
    below = SO3_SERIES_BELOW_RAD * (1.0 - 1e-12) * AXIS
    above = SO3_SERIES_BELOW_RAD * (1.0 + 1e-12) * AXIS
    a_lo, b_lo = coefficients(so3_exp(below), below)
    a_hi, b_hi = coefficients(so3_exp(above), above)
    assert abs(a_hi - a_lo) < 1e-15
    assert abs(b_hi - b_lo) < 2e-11


def test_so3_exp_of_zero_is_identity_and_it_vectorises() -> None:
    np.testing.assert_array_equal(so3_exp(np.zeros(3)), np.eye(3))
    rng = np.random.default_rng(0)
    phi = rng.normal(size=(2, 4, 3))
    R = so3_exp(phi)
    assert R.shape == (2, 4, 3, 3)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-15
    )
    np.testing.assert_allclose(R[1, 2], Rotation.from_rotvec(phi[1, 2]).as_matrix(), atol=1e-15)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-5, 1e-3, 0.1, 2.0])
def test_so3_exp_one_equals_so3_exp(scale: float) -> None:
    rng = np.random.default_rng(7)
    for phi in rng.normal(size=(20, 3)) * scale:
        np.testing.assert_allclose(so3_exp_one(phi), so3_exp(phi), rtol=0, atol=1e-15)

"""Quaternions to Z-Y-X Euler angles and their rates, against scipy and finite differences."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from toolkit.geometry.rotations import euler_rates_zyx, quaternion_to_euler_zyx


def test_euler_rates_match_finite_differences() -> None:
    rng = np.random.default_rng(3)
    dt = 1e-6
    for _ in range(20):
        angles = rng.uniform([-3, -1.2, -1.0], [3, 1.2, 1.0])  # yaw, pitch, roll
        omega = rng.normal(0, 1, 3)  # body rates p, q, r
        r0 = Rotation.from_euler("ZYX", angles)
        r1 = r0 * Rotation.from_rotvec(omega * dt)  # body-frame rotation increment
        d = (r1.as_euler("ZYX") - angles + np.pi) % (2 * np.pi) - np.pi
        roll_rate, pitch_rate, yaw_rate = euler_rates_zyx(
            np.array([angles[2]]), np.array([angles[1]]), *(np.array([w]) for w in omega)
        )
        np.testing.assert_allclose(
            [roll_rate[0], pitch_rate[0], yaw_rate[0]], d[::-1] / dt, rtol=1e-4, atol=1e-4
        )


def test_quaternion_to_euler_matches_scipy() -> None:
    rng = np.random.default_rng(5)
    rot = Rotation.random(50, random_state=7)
    q = rot.as_quat() * rng.uniform(0.5, 2.0, (50, 1))
    roll, pitch, yaw = quaternion_to_euler_zyx(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    expect = rot.as_euler("ZYX")
    np.testing.assert_allclose(np.stack([yaw, pitch, roll], axis=1), expect, atol=1e-9)

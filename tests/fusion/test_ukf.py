"""The pose UKF: angle wrapping, gating, the vectorised process model."""

from __future__ import annotations

import numpy as np

from toolkit.fusion.rotations import euler_to_rot, rot_to_euler, wrap_angle
from toolkit.fusion.ukf import (
    DIM_X,
    GRAVITY,
    ImuIncrement,
    NoiseModel,
    PoseUKF,
    angle_mean,
    angle_residual,
    gps_model,
    propagate,
    state_mean,
    state_residual,
)


def make_filter(yaw: float = 0.0) -> PoseUKF:
    x0 = np.zeros(DIM_X)
    x0[8] = yaw
    P0 = np.diag([1.0] * 3 + [0.25] * 3 + [0.01] * 3 + [1e-4] * 3 + [1e-6] * 3)
    return PoseUKF(x0, P0, NoiseModel(0.5, 0.01, 0.001, 0.0001), alpha=1e-3, beta=2.0, kappa=0.0)


def test_residuals_wrap_angles() -> None:
    a = np.zeros(DIM_X)
    b = np.zeros(DIM_X)
    a[8], b[8] = np.pi - 0.01, -np.pi + 0.01
    assert np.isclose(state_residual(a, b)[8], -0.02)
    assert np.isclose(angle_residual(np.array([-np.pi + 0.01]), np.array([np.pi - 0.01]))[0], 0.02)


def test_means_wrap_angles() -> None:
    sig = np.zeros((3, DIM_X))
    sig[:, 8] = [np.pi - 0.01, -np.pi + 0.01, np.pi - 0.01]
    wm = np.array([1 / 3, 1 / 3, 1 / 3])
    m = state_mean(sig, wm)
    assert abs(abs(m[8]) - (np.pi - 0.01 / 3)) < 1e-9
    z = angle_mean(np.array([[np.pi - 0.02], [-np.pi + 0.02]]), np.array([0.5, 0.5]))
    assert np.isclose(abs(z[0]), np.pi)


def test_yaw_update_across_pi_moves_the_short_way() -> None:
    ukf = make_filter(yaw=np.pi - 0.02)
    from toolkit.fusion.ukf import yaw_model

    ok = ukf.update_gated(
        "heading",
        np.array([-np.pi + 0.02]),
        np.array([[1e-4]]),
        yaw_model,
        15.14,
        residual_fn=angle_residual,
        mean_fn=angle_mean,
    )
    assert ok
    assert abs(wrap_angle(ukf.x[8] - np.pi)) < 0.02  # moved towards +-pi, not through 0


def test_gating_rejects_an_outlier_and_counts_it() -> None:
    ukf = make_filter()
    hx = gps_model(np.zeros(3))
    R = np.eye(3) * 0.25
    assert ukf.update_gated("gps", np.array([0.5, -0.3, 0.2]), R, hx, 21.11)
    x_before = ukf.x.copy()
    assert not ukf.update_gated("gps", np.array([50.0, 0.0, 0.0]), R, hx, 21.11)
    assert ukf.gated["gps"] == 1 and ukf.accepted["gps"] == 1
    assert ukf.last_d2 > 21.11
    np.testing.assert_array_equal(ukf.x, x_before)


def test_process_model_level_constant_speed() -> None:
    """Level, 10 m/s east, IMU reading exactly -g: position advances v T, nothing else."""
    x = np.zeros((1, DIM_X))
    x[0, 3] = 10.0
    inc = ImuIncrement(np.zeros(3), np.zeros(3))
    for _ in range(10):
        inc.add(-GRAVITY, np.zeros(3), 0.01)
    out = propagate(x, inc)[0]
    np.testing.assert_allclose(out[:3], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[3:6], [10.0, 0.0, 0.0], atol=1e-12)


def test_process_model_turns_with_gyro_and_matches_predict() -> None:
    inc = ImuIncrement(np.zeros(3), np.zeros(3))
    for _ in range(10):
        inc.add(-GRAVITY, np.array([0.0, 0.0, 0.1]), 0.01)
    x = np.zeros((1, DIM_X))
    assert np.isclose(propagate(x, inc)[0, 8], 0.01)
    ukf = make_filter()
    ukf.predict_imu(inc)
    assert np.isclose(ukf.x[8], 0.01, atol=1e-9)
    assert ukf.P[0, 0] > 1.0  # covariance grew


def test_euler_round_trip() -> None:
    rpy = np.array([[0.1, -0.2, 3.0], [-0.3, 0.4, -2.0]])
    np.testing.assert_allclose(rot_to_euler(euler_to_rot(rpy)), rpy, atol=1e-12)

"""The pose UKF: gating, and the predict, update and restart pinned against the closed-form
linear Kalman filter where the UKF is exact."""

from __future__ import annotations

import numpy as np
import pytest

from tests.fusion.test_process import stationary_increment
from toolkit.fusion.measurements import Measurement, gps_model, wheel_model, yaw_model
from toolkit.fusion.process import ImuIncrement, NoiseModel, propagate
from toolkit.fusion.state import (
    ATT,
    BA,
    BG,
    DEAD_RECKONING_GIVEN,
    DIM_X,
    GRAVITY,
    MOTION,
    POS,
    SCALE,
    VEL,
    YAW,
    angle_mean,
    angle_residual,
)
from toolkit.fusion.ukf import PoseUKF
from toolkit.geometry.rotations import euler_to_rot, rot_to_euler, wrap_angle

#: Process noise densities of the test filter: accel, gyro, accel bias walk, gyro bias walk.
NOISE = NoiseModel(accel=0.5, gyro=0.01, accel_bias_walk=0.001, gyro_bias_walk=0.0001)
#: Initial standard deviations of the test filter, per state block.
STD0 = {"pos": 1.0, "vel": 0.5, "att": 0.1, "ba": 0.01, "bg": 0.001, "scale": 0.01}


def initial_covariance() -> np.ndarray:
    """Diagonal P0 (16, 16) from :data:`STD0`."""
    std = np.empty(DIM_X)
    std[POS], std[VEL], std[ATT] = STD0["pos"], STD0["vel"], STD0["att"]
    std[BA], std[BG], std[SCALE] = STD0["ba"], STD0["bg"], STD0["scale"]
    return np.diag(std**2)


def make_filter(yaw: float = 0.0, P0: np.ndarray | None = None) -> PoseUKF:
    x0 = np.zeros(DIM_X)
    x0[YAW] = yaw
    P = initial_covariance() if P0 is None else P0
    return PoseUKF(x0, P, NOISE, alpha=1e-3, beta=2.0, kappa=0.0)


def correlated_covariance(seed: int) -> np.ndarray:
    """An SPD P (16, 16) with the scales of :func:`initial_covariance` and strong correlations."""
    rng = np.random.default_rng(seed)
    std = np.sqrt(np.diag(initial_covariance()))
    A = rng.normal(size=(DIM_X, DIM_X))
    C = A @ A.T + 0.5 * np.eye(DIM_X)
    d = np.sqrt(np.diag(C))
    return np.asarray((C / np.outer(d, d)) * np.outer(std, std), dtype=np.float64)


def test_state_views_are_read_only() -> None:
    ukf = make_filter()
    with pytest.raises(ValueError, match="read-only"):
        ukf.x[0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        ukf.P[0, 0] = 1.0


def test_update_equals_the_kalman_update_for_a_linear_measurement() -> None:
    """GPS with no lever arm measures z = H x, H = [I3 0]: linear, so the UKF is exact.

    Closed form: S = H P H^T + R, K = P H^T S^-1, x+ = x + K (z - H x), P+ = P - K S K^T, and
    the gate's d2 = y^T S^-1 y. The correlated P makes every state move, not only position.
    """
    P = correlated_covariance(seed=2)
    ukf = make_filter(P0=P)
    x = ukf.x.copy()
    z = np.array([0.8, -0.5, 0.3])
    R = np.diag([0.09, 0.16, 0.25])
    H = np.zeros((3, DIM_X))
    H[:, POS] = np.eye(3)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    y = z - H @ x
    x_expected = x + K @ y
    P_expected = P - K @ S @ K.T

    assert ukf.update("gps", z, R, gps_model(np.zeros(3)), gate_chi2=1e9)

    assert ukf.last_d2 == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-9)
    np.testing.assert_allclose(ukf.x, x_expected, rtol=0, atol=1e-11)
    np.testing.assert_allclose(ukf.P, P_expected, rtol=0, atol=1e-11 * np.abs(P).max())
    assert np.abs(ukf.x - x).max() > 0.1  # the update moved the state: the test has teeth


def test_yaw_update_across_pi_moves_the_short_way() -> None:
    ukf = make_filter(yaw=np.pi - 0.02)
    ok = ukf.update(
        "heading",
        np.array([-np.pi + 0.02]),
        np.array([[1e-4]]),
        yaw_model,
        15.14,
        residual_fn=angle_residual,
        mean_fn=angle_mean,
    )
    assert ok
    assert abs(wrap_angle(ukf.x[YAW] - np.pi)) < 0.02  # moved towards +-pi, not through 0


def test_gating_rejects_an_outlier_and_counts_it() -> None:
    ukf = make_filter()
    hx = gps_model(np.zeros(3))
    R = np.eye(3) * 0.25
    assert ukf.update("gps", np.array([0.5, -0.3, 0.2]), R, hx, 21.11)
    x_before = ukf.x.copy()
    P_before = ukf.P.copy()
    assert not ukf.update("gps", np.array([50.0, 0.0, 0.0]), R, hx, 21.11)
    assert ukf.gated["gps"] == 1 and ukf.accepted["gps"] == 1
    assert ukf.gated["wheels"] == 0
    assert ukf.last_d2 > 21.11
    np.testing.assert_array_equal(ukf.x, x_before)
    np.testing.assert_array_equal(ukf.P, P_before)


def test_a_robust_block_beyond_its_gate_is_down_weighted_to_the_gate() -> None:
    """A ``robust`` measurement beyond its gate is used with ``S' = (d2 / g) S``: the
    closed-form Kalman update of the linear GPS position with ``R' = R + (d2/g - 1) S``, and
    the innovation's distance under ``S'`` is the gate; counted accepted and down-weighted.
    Inside the gate a robust block is the ordinary update."""
    hx, R, gate = gps_model(np.zeros(3)), np.eye(3) * 0.25, 21.11
    z = np.array([6.0, -2.0, 1.0])
    ukf = make_filter()
    P = ukf.P.copy()
    assert ukf.update_joint([Measurement("gps", z, R, hx, gate, robust=True)]) == [True]
    S = P[POS, POS] + R
    d2 = float(z @ np.linalg.solve(S, z))
    assert d2 > gate
    S_inflated = S * d2 / gate
    assert float(z @ np.linalg.solve(S_inflated, z)) == pytest.approx(gate)
    K = np.linalg.solve(S_inflated, P[POS, :]).T  # P H^T S'^-1, H selects the position
    np.testing.assert_allclose(ukf.x, K @ z, atol=1e-9)
    np.testing.assert_allclose(ukf.P, P - K @ S_inflated @ K.T, atol=1e-9)
    assert ukf.accepted["gps"] == 1 and ukf.down_weighted["gps"] == 1 and ukf.gated["gps"] == 0

    inside, plain = make_filter(), make_filter()
    small = np.array([0.5, -0.3, 0.2])
    inside.update_joint([Measurement("gps", small, R, hx, gate, robust=True)])
    plain.update_joint([Measurement("gps", small, R, hx, gate)])
    np.testing.assert_array_equal(inside.x, plain.x)
    assert inside.down_weighted["gps"] == 0


def test_predict_equals_the_kalman_predict_for_zero_motion() -> None:
    """Level, at rest, zero biases, the IMU reading exactly gravity: the process model moves
    only position by velocity, p' = p + v T, so with F = [[I, T I], [0, I]] on (p, v) the
    prediction is P' = F P F^T + Q, with Q from the documented densities (not from the
    code's NoiseModel.q, so a wrong Q fails):

        Q = diag(accel^2 T^3 / 3 + 1e-9 (pos), accel^2 T (vel), gyro^2 T (att),
                 accel_bias_walk^2 T + 1e-14 (ba), gyro_bias_walk^2 T + 1e-16 (bg))

    The attitude and bias variances are made tiny so that their (nonlinear) effect on
    position and velocity, of order g^2 T^2 P_att, stays far below the tolerance.
    """
    T = 0.1
    P = np.diag(np.full(DIM_X, 1e-18))
    P[POS, POS] = np.eye(3) * 0.5
    P[VEL, VEL] = np.eye(3) * 0.2
    P[POS, VEL] = P[VEL, POS] = np.eye(3) * -0.15  # correlated, so F P F^T has cross terms
    ukf = make_filter(P0=P)

    ukf.predict(stationary_increment(T, steps=10))

    F = np.eye(DIM_X)
    F[POS, VEL] = np.eye(3) * T
    q = np.empty(DIM_X)
    q[POS] = NOISE.accel**2 * T**3 / 3.0 + 1e-9
    q[VEL] = NOISE.accel**2 * T
    q[ATT] = NOISE.gyro**2 * T
    q[BA] = NOISE.accel_bias_walk**2 * T + 1e-14
    q[BG] = NOISE.gyro_bias_walk**2 * T + 1e-16
    q[SCALE] = NOISE.wheel_scale_walk**2 * T + 1e-14
    P_expected = F @ P @ F.T + np.diag(q)
    np.testing.assert_allclose(ukf.x, np.zeros(DIM_X), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ukf.P, P_expected, rtol=0, atol=1e-13)


def test_restart_keeps_the_covariance_positive_definite() -> None:
    """A P whose strong cross-correlations the old element-wise max(P, P0) made indefinite.

    Two error modes share px, vx, yaw and the z gyro bias with mixed signs; all four
    variances exceed P0's, so max(P, P0) keeps them and only zeroes the negative
    cross-covariances, which leaves an indefinite matrix.
    """
    P0 = initial_covariance()
    idx = [POS.start, VEL.start, YAW, BG.start + 2]  # px, vx, yaw, bgz
    std = 2.0 * np.sqrt(np.diag(P0)[idx])
    u, w = np.array([1.0, 1.0, 0.0, 1.0]), np.array([1.0, 0.0, 1.0, -1.0])
    corr = (np.outer(u, u) + np.outer(w, w) + 0.01 * np.eye(4)) / 2.01
    P = 4.0 * P0
    P[np.ix_(idx, idx)] = corr * np.outer(std, std)
    assert np.linalg.eigvalsh(P).min() > 0
    assert np.linalg.eigvalsh(np.maximum(P, P0)).min() < 0  # the old rule's failure

    ukf = make_filter(P0=P)
    ukf.restart(P0)
    P_new = ukf.P.copy()

    np.testing.assert_array_equal(P_new, P_new.T)
    assert np.linalg.eigvalsh(P_new).min() > 0
    # At least as uncertain as before, and as the start in position, velocity, attitude.
    assert np.linalg.eigvalsh(P_new - P).min() > -1e-12
    assert np.linalg.eigvalsh(P_new[MOTION, MOTION] - P0[MOTION, MOTION]).min() > -1e-12
    # The biases keep their covariance and their correlation with the motion.
    np.testing.assert_array_equal(P_new[BA.start :, :], P[BA.start :, :])
    # Idempotent: the estimator restarts at every epoch inside a gap.
    ukf.restart(P0)
    np.testing.assert_allclose(ukf.P, P_new, rtol=0, atol=1e-12 * np.abs(P_new).max())

    # The next predict and update run (their sigma points need a Cholesky of P).
    ukf.predict(stationary_increment(0.1, steps=10))
    assert ukf.update(
        "gps", np.array([0.3, 0.1, -0.2]), np.eye(3) * 0.25, gps_model(np.zeros(3)), 1e9
    )
    assert np.linalg.eigvalsh(ukf.P).min() > 0


def test_restart_of_an_uncertain_filter_changes_nothing() -> None:
    """Directions already more uncertain than P0 keep their covariance."""
    P = 3.0 * correlated_covariance(seed=4)
    P[MOTION, MOTION] += 2.0 * initial_covariance()[MOTION, MOTION]
    ukf = make_filter(P0=P)
    ukf.restart(initial_covariance())
    np.testing.assert_allclose(ukf.P, P, rtol=0, atol=1e-12 * np.abs(P).max())


def test_process_model_turns_with_gyro_and_predict_follows() -> None:
    inc = ImuIncrement(np.zeros(3), np.zeros(3))
    for _ in range(10):
        inc.add(-GRAVITY, np.array([0.0, 0.0, 0.1]), 0.01)
    x = np.zeros((1, DIM_X))
    assert np.isclose(propagate(x, inc)[0, YAW], 0.01)
    ukf = make_filter()
    ukf.predict(inc)
    assert np.isclose(ukf.x[YAW], 0.01, atol=1e-9)


def test_euler_round_trip() -> None:
    rpy = np.array([[0.1, -0.2, 3.0], [-0.3, 0.4, -2.0]])
    np.testing.assert_allclose(rot_to_euler(euler_to_rot(rpy)), rpy, atol=1e-12)


def test_joint_update_equals_the_kalman_update_for_linear_measurements() -> None:
    """GPS (no lever arm) and yaw at once, both linear: one stacked Kalman update, H = [[I3
    at POS], [e_yaw]], R = blockdiag(R_gps, r_yaw); the per-block d2 are the marginal ones."""
    P = correlated_covariance(seed=5)
    ukf = make_filter(P0=P)
    x = ukf.x.copy()
    z = np.array([0.8, -0.5, 0.3, 0.05])
    R = np.diag([0.09, 0.16, 0.25, 1e-3])
    H = np.zeros((4, DIM_X))
    H[:3, POS] = np.eye(3)
    H[3, YAW] = 1.0
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    y = z - H @ x
    flags = ukf.update_joint(
        [
            Measurement("gps", z[:3], R[:3, :3], gps_model(np.zeros(3)), 1e9),
            Measurement("heading", z[3:], R[3:, 3:], yaw_model, 1e9, angle_mean, angle_residual),
        ]
    )
    assert flags == [True, True]
    np.testing.assert_allclose(ukf.x, x + K @ y, rtol=0, atol=1e-11)
    np.testing.assert_allclose(ukf.P, P - K @ S @ K.T, rtol=0, atol=1e-11 * np.abs(P).max())
    assert ukf.last_d2 == pytest.approx(float(y[3] ** 2 / S[3, 3]), rel=1e-9)
    assert ukf.accepted["gps"] == ukf.accepted["heading"] == 1


def test_conditioned_update_equals_the_kalman_update_of_the_regression_residual() -> None:
    """Conditioned on ``c`` (dead reckoning's position, yaw, z gyro bias, wheel scale), a
    linear measurement ``z = H x + v`` updates only ``e = x_r - A x_c`` (``A = P_rc
    P_cc^-1``): ``x_c`` and ``P_cc`` stay, ``P_rc+ = A P_cc``, ``P_rr+ = P_r|c+ + A P_cc
    A^T``, with ``P_r|c+`` the Kalman update of ``P_r|c`` by ``H_r`` (PoseUKF._conditioned)."""
    rng = np.random.default_rng(11)
    P = correlated_covariance(seed=7)
    ukf = make_filter(P0=P)
    x = ukf.x.copy()
    H = rng.normal(size=(2, DIM_X))
    R = np.diag([0.04, 0.09])
    z = np.array([0.3, -0.2])
    c = np.asarray(DEAD_RECKONING_GIVEN)
    r = np.setdiff1d(np.arange(DIM_X), c)
    A = P[np.ix_(r, c)] @ np.linalg.inv(P[np.ix_(c, c)])
    P_rc = P[np.ix_(r, r)] - A @ P[np.ix_(c, r)]
    H_r = H[:, r]
    S = H_r @ P_rc @ H_r.T + R
    K = P_rc @ H_r.T @ np.linalg.inv(S)
    flags = ukf.update_joint(
        [Measurement("linear", z, R, lambda sig: sig @ H.T, 1e9)], given=DEAD_RECKONING_GIVEN
    )
    assert flags == [True]
    x_exp = x.copy()
    x_exp[r] += K @ (z - H @ x)
    P_exp = P.copy()
    P_exp[np.ix_(r, r)] = P_rc - K @ S @ K.T + A @ P[np.ix_(c, c)] @ A.T
    P_exp[np.ix_(r, c)] = A @ P[np.ix_(c, c)]
    P_exp[np.ix_(c, r)] = P_exp[np.ix_(r, c)].T
    np.testing.assert_allclose(ukf.x, x_exp, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ukf.P, P_exp, rtol=0, atol=1e-8 * np.abs(P).max())
    # The conditioned states are neither moved nor made more certain; the update only
    # removes uncertainty (P - P+ is positive semi-definite) and P+ stays positive definite.
    np.testing.assert_array_equal(ukf.x[c], x[c])
    np.testing.assert_allclose(ukf.P[np.ix_(c, c)], P[np.ix_(c, c)], rtol=1e-12)
    assert np.linalg.eigvalsh(P - ukf.P).min() > -1e-10 * np.abs(P).max()
    assert np.linalg.eigvalsh(ukf.P).min() > 0.0


def test_an_unconditioned_update_moves_what_a_conditioned_one_holds() -> None:
    """The same wheel-speed update, free and conditioned: free, the cross-covariances make it
    move position and yaw (the dead-reckoning drift ``_conditioned`` prevents); conditioned,
    it moves the velocity and leaves them where they were."""
    P = correlated_covariance(seed=3)
    free, held = make_filter(P0=P), make_filter(P0=P)
    for ukf, given in ((free, ()), (held, DEAD_RECKONING_GIVEN)):
        ukf.update_joint(
            [
                Measurement(
                    "wheels",
                    np.array([1.0]),
                    np.array([[0.01]]),
                    wheel_model(np.zeros(3), np.zeros(3)),
                    1e9,
                )
            ],
            given=given,
        )
    c = list(DEAD_RECKONING_GIVEN)
    assert np.abs(free.x[c]).max() > 1e-3
    np.testing.assert_array_equal(held.x[c], np.zeros(len(c)))
    assert np.abs(held.x[VEL] - make_filter().x[VEL]).max() > 1e-2


def test_joint_update_gates_each_sensor_on_its_own() -> None:
    """A wild fix is rejected; the yaw measured with it still updates, alone."""
    ukf = make_filter()
    alone = make_filter()
    z_yaw, r_yaw = np.array([0.05]), np.array([[1e-3]])
    flags = ukf.update_joint(
        [
            Measurement(
                "gps", np.array([500.0, 0.0, 0.0]), np.eye(3), gps_model(np.zeros(3)), 21.0
            ),
            Measurement("heading", z_yaw, r_yaw, yaw_model, 15.0, angle_mean, angle_residual),
        ]
    )
    assert flags == [False, True]
    assert ukf.gated["gps"] == 1 and ukf.accepted["heading"] == 1
    alone.update(
        "heading", z_yaw, r_yaw, yaw_model, 15.0, mean_fn=angle_mean, residual_fn=angle_residual
    )
    np.testing.assert_allclose(ukf.x, alone.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ukf.P, alone.P, rtol=0, atol=1e-15)


def test_wheel_updates_learn_the_scale_error() -> None:
    """A filter told its velocity (GPS-like, 10 m/s east) and an odometer reading 0.5 % high
    ends with ks near 0.005; without the state it could only bias the velocity. (Moving from
    the start: at rest the reading says nothing about the scale.)"""
    x0 = np.zeros(DIM_X)
    x0[VEL.start] = 10.0
    # Attitude known to 1 mrad: a 0.1 rad uncertainty would itself lower the expected
    # forward speed by (sigma_pitch^2 + sigma_yaw^2) / 2 = 1 %, which the UKF rightly sees.
    P0 = initial_covariance()
    P0[ATT, ATT] = np.eye(3) * 1e-6
    ukf = PoseUKF(x0, P0, NoiseModel(0.5, 1e-4, 0.001, 0.0001), alpha=1e-3, beta=2.0, kappa=0.0)
    H_vel = np.zeros((3, DIM_X))
    H_vel[:, VEL] = np.eye(3)
    v_true = np.array([10.0, 0.0, 0.0])
    for _ in range(200):
        ukf.predict(stationary_increment(0.1, steps=10))
        ukf.update_joint(
            [
                Measurement("vel", v_true, np.eye(3) * 0.01, lambda s: s[:, VEL], 1e9),
                Measurement(
                    "wheels",
                    np.array([10.05]),
                    np.array([[0.05**2]]),
                    wheel_model(np.zeros(3), np.zeros(3)),
                    1e9,
                ),
            ]
        )
    assert ukf.x[SCALE] == pytest.approx(0.005, abs=5e-4)
    assert ukf.x[VEL.start] == pytest.approx(10.0, abs=0.01)


def test_reset_motion_replaces_position_and_velocity_only() -> None:
    P = correlated_covariance(seed=6)
    ukf = make_filter(P0=P)
    x_before = ukf.x.copy()
    P0 = initial_covariance()
    target = np.array([100.0, -50.0, 2.0, 1.0, 0.5, 0.0])
    ukf.reset_motion(target, P0)
    np.testing.assert_array_equal(ukf.x[POS.start : VEL.stop], target)
    np.testing.assert_array_equal(ukf.x[ATT.start :], x_before[ATT.start :])
    pv = slice(POS.start, VEL.stop)
    np.testing.assert_array_equal(ukf.P[pv, pv], P0[pv, pv])
    np.testing.assert_array_equal(ukf.P[pv, ATT.start :], 0.0)
    np.testing.assert_array_equal(ukf.P[ATT.start :, ATT.start :], P[ATT.start :, ATT.start :])
    assert np.linalg.eigvalsh(ukf.P).min() > 0

"""The simulated vehicle: geometry, suspension dynamics and the race's speed controller.

Frames: ``base_link`` has x forward, y left, z up, its origin on the ground below the centre
of the rear axle (at static equilibrium on flat ground). Pitch is positive nose-down and roll
positive left-side-up (right-handed rotations about y and x).

The suspension is the classic linear 7-degree-of-freedom full-car model: body heave ``zs``,
pitch ``theta`` and roll ``phi`` on four spring-damper corners, each over an unsprung wheel
mass ``zu_i`` on a tyre spring that follows the road height ``r_i`` under it::

    F_i      = ks (zu_i - zc_i) + cs (zu_i' - zc_i')          zc_i = zs - x_i theta + y_i phi
    ms zs''  = sum F_i
    Iy theta'' = -sum x_i F_i - ms h a_x                      (squat under acceleration)
    Ix phi''   =  sum y_i F_i + ms h a_y                      (body roll in turns)
    mu zu_i''  = -F_i + kt (r_i - zu_i)

with ``x_i, y_i`` the corner's position relative to the centre of gravity. It has body
bounce near 1.3 Hz, pitch and roll modes near 1-2 Hz and wheel hop near 11 Hz. Heights are
absolute (the road includes the hills), so the body follows the terrain's slope and the
pitch and roll it produces are the vehicle's true attitude.

The model is linear and time-invariant, so it is discretised once (zero-order hold at the
dynamics rate) and diagonalised: each mode is then a first-order complex recursion that
``scipy.signal.lfilter`` runs over a whole block of samples at C speed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.signal import lfilter

FloatArray = NDArray[np.floating[Any]]


@dataclass(frozen=True)
class VehicleParams:
    """A VW Touareg like Stanley. Lengths in m, masses in kg, inertias in kg m^2."""

    wheelbase_m: float = 2.855
    track_m: float = 1.65
    cg_from_rear_m: float = 1.35
    cg_height_m: float = 0.75
    sprung_mass_kg: float = 2200.0
    pitch_inertia_kgm2: float = 3800.0
    roll_inertia_kgm2: float = 850.0
    unsprung_mass_kg: float = 55.0
    spring_n_per_m: float = 37000.0
    damper_ns_per_m: float = 4500.0
    tyre_n_per_m: float = 260000.0
    wheel_radius_m: float = 0.38

    def corners(self) -> tuple[FloatArray, FloatArray]:
        """Corner positions relative to the CG, order FL, FR, RL, RR: (x_m, y_m), each (4,)."""
        a = self.wheelbase_m - self.cg_from_rear_m
        b = self.cg_from_rear_m
        h = self.track_m / 2
        return np.array([a, a, -b, -b]), np.array([h, -h, h, -h])


N_STATES = 14
N_INPUTS = 6  # r_FL, r_FR, r_RL, r_RR, a_x (m/s^2), a_y (m/s^2)


def full_car_matrices(p: VehicleParams) -> tuple[FloatArray, FloatArray]:
    """Continuous-time ``x' = A x + B u`` of the 7-DOF model.

    State (14,): ``[zs, theta, phi, zu_FL, zu_FR, zu_RL, zu_RR]`` then their rates.
    Input (6,): road heights under the four wheels, then longitudinal and lateral
    acceleration of the vehicle (which load the body through the CG height).
    """
    xi, yi = p.corners()
    # zc = G q_body, q_body = (zs, theta, phi)
    G = np.stack([np.ones(4), -xi, yi], axis=1)  # (4, 3)
    M_body = np.diag([p.sprung_mass_kg, p.pitch_inertia_kgm2, p.roll_inertia_kgm2])
    ks, cs, kt, mu = p.spring_n_per_m, p.damper_ns_per_m, p.tyre_n_per_m, p.unsprung_mass_kg

    # Generalised stiffness K and damping C over q = (zs, theta, phi, zu1..4).
    K = np.zeros((7, 7))
    C = np.zeros((7, 7))
    # Body: G^T F with F = ks (zu - G q) + cs (zu' - G q')
    K[:3, :3] = ks * G.T @ G
    K[:3, 3:] = -ks * G.T
    K[3:, :3] = -ks * G
    K[3:, 3:] = (ks + kt) * np.eye(4)
    C[:3, :3] = cs * G.T @ G
    C[:3, 3:] = -cs * G.T
    C[3:, :3] = -cs * G
    C[3:, 3:] = cs * np.eye(4)
    M = np.zeros((7, 7))
    M[:3, :3] = M_body
    M[3:, 3:] = mu * np.eye(4)
    Minv = np.linalg.inv(M)

    # Inputs: road heights act through the tyres; accelerations through the CG height.
    F_u = np.zeros((7, N_INPUTS))
    F_u[3:, :4] = kt * np.eye(4)
    F_u[1, 4] = -p.sprung_mass_kg * p.cg_height_m  # squat: nose up under acceleration
    F_u[2, 5] = p.sprung_mass_kg * p.cg_height_m  # roll outwards in a turn

    A = np.zeros((N_STATES, N_STATES))
    A[:7, 7:] = np.eye(7)
    A[7:, :7] = -Minv @ K
    A[7:, 7:] = -Minv @ C
    B = np.zeros((N_STATES, N_INPUTS))
    B[7:, :] = Minv @ F_u
    return A, B


@dataclass(frozen=True)
class ModalSuspension:
    """The discretised full-car model in modal form: ``z[k+1] = lam z[k] + Bm u[k]``.

    ``x = V z``. ``step_block`` runs a block of inputs through every mode with ``lfilter``.
    """

    A: FloatArray
    B: FloatArray
    lam: NDArray[np.complex128]  # (14,)
    V: NDArray[np.complex128]  # (14, 14)
    Bm: NDArray[np.complex128]  # (14, 6)
    dt_s: float

    @classmethod
    def build(cls, params: VehicleParams, dt_s: float) -> ModalSuspension:
        A, B = full_car_matrices(params)
        # Zero-order-hold discretisation via the block matrix exponential.
        blk = np.zeros((N_STATES + N_INPUTS, N_STATES + N_INPUTS))
        blk[:N_STATES, :N_STATES] = A
        blk[:N_STATES, N_STATES:] = B
        e = expm(blk * dt_s)
        Ad, Bd = e[:N_STATES, :N_STATES], e[:N_STATES, N_STATES:]
        lam, V = np.linalg.eig(Ad)
        Bm = np.linalg.solve(V, Bd)
        return cls(A=A, B=B, lam=lam, V=V, Bm=Bm, dt_s=dt_s)

    def equilibrium(self, u: FloatArray) -> FloatArray:
        """The static state for constant input ``u`` (6,): solves ``A x + B u = 0``."""
        return np.linalg.solve(self.A, -self.B @ u)

    def step_block(self, x0: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Advance from state ``x0`` (14,) through inputs ``u`` (n, 6).

        Returns ``states`` (n, 14), the state at the *start* of each sample, and the state
        after the last sample (14,).
        """
        z0 = np.linalg.solve(self.V, x0.astype(np.complex128))
        drive = u @ self.Bm.T  # (n, 14)
        n = u.shape[0]
        z = np.empty((n + 1, N_STATES), dtype=np.complex128)
        z[0] = z0
        for m in range(N_STATES):
            # y[k] = lam y[k-1] + drive[k], y[-1] = z0  ->  y[k] = z[k+1]
            z[1:, m], _ = lfilter([1.0], [1.0, -self.lam[m]], drive[:, m], zi=[self.lam[m] * z0[m]])
        states = (z @ self.V.T).real
        return states[:-1], states[-1]

    def accelerations(self, states: FloatArray, u: FloatArray) -> FloatArray:
        """Second derivatives of the 7 coordinates, (n, 7), from ``x' = A x + B u``."""
        return states @ self.A[7:].T + u @ self.B[7:].T


@dataclass(frozen=True)
class ReactiveSpeedParams:
    """The race's reactive speed controller (Thrun et al. 2006b), after Sect. 7.2 of the paper.

    After a measured shock above ``shock_threshold_g`` the speed cap drops to
    ``(1 - slowdown_fraction)`` of the current speed (never below ``min_speed_mps``) and then
    recovers at ``recovery_mps_per_m`` per metre driven.
    """

    shock_threshold_g: float = 0.35
    slowdown_fraction: float = 0.3
    min_speed_mps: float = 4.0
    recovery_mps_per_m: float = 0.05
    accel_mps2: float = 1.2
    brake_mps2: float = 2.5
    lateral_accel_mps2: float = 2.0
    enabled: bool = True


@dataclass
class ReactiveSpeedController:
    """Speed target from the route's limits, curvature and the reactive shock cap."""

    params: ReactiveSpeedParams
    cap_mps: float = np.inf

    def on_shock(self, shock_g: float, speed_mps: float) -> None:
        if self.params.enabled and shock_g > self.params.shock_threshold_g:
            new_cap = max(
                self.params.min_speed_mps, speed_mps * (1 - self.params.slowdown_fraction)
            )
            self.cap_mps = min(self.cap_mps, new_cap)

    def recover(self, distance_m: float) -> None:
        if np.isfinite(self.cap_mps):
            self.cap_mps += self.params.recovery_mps_per_m * distance_m
            if self.cap_mps > 40.0:
                self.cap_mps = np.inf

    def acceleration(self, speed_mps: float, limit_mps: float) -> float:
        target = min(limit_mps, self.cap_mps)
        a = 0.8 * (target - speed_mps)
        return float(np.clip(a, -self.params.brake_mps2, self.params.accel_mps2))


def safe_speed_profile(
    s_m: FloatArray, limit_mps: FloatArray, curvature_per_m: FloatArray, p: ReactiveSpeedParams
) -> FloatArray:
    """Speed limit along the route that also respects curves and braking ahead of them.

    ``v <= sqrt(a_lat / |kappa|)`` in bends, and a backward pass so that the vehicle can
    brake at ``brake_mps2`` (with margin) to every lower limit ahead.
    """
    v = np.minimum(
        limit_mps, np.sqrt(p.lateral_accel_mps2 / np.maximum(np.abs(curvature_per_m), 1e-9))
    )
    ds = np.diff(s_m)
    a = 0.5 * p.brake_mps2
    out = v.copy()
    for i in range(out.size - 2, -1, -1):
        out[i] = min(out[i], np.sqrt(out[i + 1] ** 2 + 2 * a * ds[i]))
    return out

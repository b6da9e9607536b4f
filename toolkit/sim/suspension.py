"""The full-car suspension: 7 degrees of freedom, unilateral tyres and bump stops, integrated
exactly between contact changes.

The classic 7-degree-of-freedom full-car model (Gillespie 1992, ch. 5; Wong 2001, ch. 7):
body heave ``zs``, pitch ``theta`` and roll ``phi`` on four spring-damper corners, each over
an unsprung wheel mass ``zu_i`` on a tyre. Forces are deviations from the static equilibrium
on flat ground, where gravity, the springs' preload and the static wheel loads ``W_i``
cancel::

    F_i  = ks (zu_i - zc_i) + cs (zu_i' - zc_i')               zc_i = zs - x_i theta + y_i phi
    T_i  = max(0, W_i + kt (r_i - zu_i) + ct (r_i' - zu_i'))   total tyre force, never a pull
    ms zs''    =  sum F_i
    Iy theta'' = -sum x_i F_i - ms h a_x                       (squat under acceleration)
    Ix phi''   =  sum y_i F_i + ms h a_y                       (body roll in turns)
    mu zu_i''  = -F_i + T_i - W_i

with ``x_i, y_i`` the corner's position relative to the centre of gravity and ``r_i`` the
tyre's *effective* road height (:mod:`toolkit.sim.tyre`). While a tyre pushes (``T_i > 0``)
its row is the linear model; when it would pull, the wheel leaves the ground and only its
weight and the spring's preload act on it (``T_i - W_i = -W_i``) until it lands again.
Heights are absolute (the road includes the hills), so the body follows the terrain's slope
and the pitch and roll it produces are the vehicle's true attitude.

**Integration.** Between contact changes the model is linear and time-invariant, so it is
discretised exactly (zero-order hold at the dynamics rate) for each of the 256 patterns of
tyres on the ground and bump stops met (each on its first use). The common case, all four
tyres down and no stop met for a whole block, runs in modal form: each mode is a first-order
complex recursion that ``scipy.signal.lfilter`` runs over the block at C speed. When a tyre
would pull at either end of some step, or a corner starts a step beyond its bump stop's
clearance, the block is redone from that step one dynamics step at a time, each step with the
discrete system of the tyres that push and the stops met throughout it
(:meth:`Suspension.step_block`); the two paths agree to round-off while no tyre lifts and no
stop is met.

References: T. D. Gillespie, *Fundamentals of Vehicle Dynamics*, SAE 1992, ch. 5 (ride);
J. Y. Wong, *Theory of Ground Vehicles*, 3rd ed., Wiley 2001, ch. 7 (vehicle ride).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.signal import lfilter

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.vehicle import VehicleParams

N_STATES = 14
# r_FL..r_RR (m), r'_FL..r'_RR (m/s), a_x (m/s^2), a_y (m/s^2), and a constant 1 that carries
# an airborne wheel's weight and spring preload and a bump stop's clearance.
N_INPUTS = 11
INPUT_ROAD = slice(0, 4)
INPUT_ROAD_RATE = slice(4, 8)
INPUT_ACCEL_X = 8
INPUT_ACCEL_Y = 9
INPUT_ONE = 10
# A contact pattern: bit i set when tyre i is on the ground, bit 4 + i when corner i's bump
# stop is met. 256 patterns; the common one, all tyres down and no bump stop met, is 15.
N_PATTERNS = 256
ALL_DOWN = 15
_TYRE_BITS = np.array([1, 2, 4, 8])
_STOP_BITS = np.array([16, 32, 64, 128])


def _pattern(down: NDArray[np.bool_], stops: NDArray[np.bool_]) -> int:
    return int(_TYRE_BITS @ down + _STOP_BITS @ stops)


def full_car_matrices(
    p: VehicleParams,
    on_ground: tuple[bool, bool, bool, bool] = (True, True, True, True),
    on_stop: tuple[bool, bool, bool, bool] = (False, False, False, False),
) -> tuple[FloatArray, FloatArray]:
    """Continuous-time ``x' = A x + B u`` of the 7-DOF model with the tyres ``on_ground``
    and the bump stops ``on_stop`` met.

    State (14,): ``[zs, theta, phi, zu_FL, zu_FR, zu_RL, zu_RR]`` then their rates.
    Input (11,): see ``N_INPUTS``. A tyre off the ground contributes no stiffness or damping;
    its wheel is pushed down by ``W_i`` (the constant input) instead. A met bump stop adds a
    spring ``kb`` between wheel and body beyond its clearance ``c``: the force
    ``kb (zu_i - zc_i - c)``, its ``-kb c`` carried by the constant input.
    """
    xi, yi = p.corners()
    # zc = G q_body, q_body = (zs, theta, phi)
    G = np.stack([np.ones(4), -xi, yi], axis=1)  # (4, 3)
    M_body = np.diag([p.sprung_mass_kg, p.pitch_inertia_kgm2, p.roll_inertia_kgm2])
    ks, cs, mu = p.spring_n_per_m, p.damper_ns_per_m, p.unsprung_mass_kg
    down = np.asarray(on_ground, dtype=np.float64)
    kt = p.tyre_n_per_m * down
    ct = p.tyre_damping_ns_per_m * down

    # Generalised stiffness K and damping C over q = (zs, theta, phi, zu1..4).
    K = np.zeros((7, 7))
    C = np.zeros((7, 7))
    # Body: G^T F with F = ks (zu - G q) + cs (zu' - G q') (+ kb (zu - G q - c) on a stop)
    kc = ks + p.bump_stop_n_per_m * np.asarray(on_stop, dtype=np.float64)  # (4,)
    K[:3, :3] = G.T @ (kc[:, None] * G)
    K[:3, 3:] = -G.T * kc[None, :]
    K[3:, :3] = -kc[:, None] * G
    K[3:, 3:] = np.diag(kc + kt)
    C[:3, :3] = cs * G.T @ G
    C[:3, 3:] = -cs * G.T
    C[3:, :3] = -cs * G
    C[3:, 3:] = np.diag(cs + ct)
    M = np.zeros((7, 7))
    M[:3, :3] = M_body
    M[3:, 3:] = mu * np.eye(4)
    Minv = np.linalg.inv(M)

    # Inputs: road heights and rates act through the tyres on the ground; accelerations
    # through the CG height; the airborne wheels' weight and preload through the constant.
    F_u = np.zeros((7, N_INPUTS))
    F_u[3:, INPUT_ROAD] = np.diag(kt)
    F_u[3:, INPUT_ROAD_RATE] = np.diag(ct)
    F_u[1, INPUT_ACCEL_X] = -p.sprung_mass_kg * p.cg_height_m  # squat: nose up under accel.
    F_u[2, INPUT_ACCEL_Y] = p.sprung_mass_kg * p.cg_height_m  # roll outwards in a turn
    F_u[3:, INPUT_ONE] = -p.static_wheel_load_n() * (1.0 - down)
    # A met stop pushes body and wheel apart only beyond its clearance: -kb c on the wheel,
    # +kb c through G on the body.
    preload = p.bump_stop_n_per_m * p.bump_stop_clearance_m * np.asarray(on_stop, dtype=float)
    F_u[3:, INPUT_ONE] += preload
    F_u[:3, INPUT_ONE] -= G.T @ preload

    A = np.zeros((N_STATES, N_STATES))
    A[:7, 7:] = np.eye(7)
    A[7:, :7] = -Minv @ K
    A[7:, 7:] = -Minv @ C
    B = np.zeros((N_STATES, N_INPUTS))
    B[7:, :] = Minv @ F_u
    return A, B


def modal_summary(p: VehicleParams) -> dict[str, float]:
    """Natural frequencies (Hz) and damping ratios of the full car's modes, all tyres down.

    From the eigenvalues ``lam`` of ``A``: ``f = |lam| / 2 pi``, ``zeta = -Re(lam) / |lam|``.
    The three slow modes are named by the body coordinate that holds most of their kinetic
    energy (heave, pitch, roll); the four fast ones are the wheels hopping, reported as the
    lowest and highest frequency and damping ratio.
    """
    A, _ = full_car_matrices(p)
    lam, vec = np.linalg.eig(A)
    upper = lam.imag > 0
    lam, vec = lam[upper], vec[:, upper]
    order = np.argsort(np.abs(lam))
    lam, vec = lam[order], vec[:, order]
    masses = np.array(
        [p.sprung_mass_kg, p.pitch_inertia_kgm2, p.roll_inertia_kgm2] + [p.unsprung_mass_kg] * 4
    )
    energy = masses[:, None] * np.abs(vec[7:]) ** 2  # (7, modes): velocities' share
    hz = np.abs(lam) / (2 * np.pi)
    zeta = -lam.real / np.abs(lam)
    out: dict[str, float] = {}
    for m in range(3):
        name = ("heave", "pitch", "roll")[int(np.argmax(energy[:3, m]))]
        out[f"{name}_hz"] = float(hz[m])
        out[f"{name}_damping_ratio"] = float(zeta[m])
    out["wheel_hop_hz_min"] = float(hz[3:].min())
    out["wheel_hop_hz_max"] = float(hz[3:].max())
    out["wheel_hop_damping_ratio_min"] = float(zeta[3:].min())
    out["wheel_hop_damping_ratio_max"] = float(zeta[3:].max())
    return out


def _zoh(A: FloatArray, B: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Zero-order-hold discretisation via the block matrix exponential."""
    blk = np.zeros((N_STATES + N_INPUTS, N_STATES + N_INPUTS))
    blk[:N_STATES, :N_STATES] = A
    blk[:N_STATES, N_STATES:] = B
    e = expm(blk * dt_s)
    return e[:N_STATES, :N_STATES], e[:N_STATES, N_STATES:]


@dataclass(frozen=True)
class SuspensionBlock:
    """One block's result: ``states`` (n, 14) at the start of each sample, ``end`` (14,) after
    the last, ``tyre_force_n`` (n, 4) the total force each tyre pushes with (>= 0, zero in the
    air), ``on_ground`` and ``on_stop`` (n, 4) the tyres down and the bump stops met during
    each sample, and ``stepped`` the number of samples that needed the step-by-step path (0
    when the modal path held for the whole block)."""

    states: FloatArray
    end: FloatArray
    tyre_force_n: FloatArray
    on_ground: NDArray[np.bool_]
    on_stop: NDArray[np.bool_]
    stepped: int

    @property
    def patterns(self) -> NDArray[np.intp]:
        """Each sample's contact pattern (n,), as :data:`N_PATTERNS` numbers them."""
        out: NDArray[np.intp] = self.on_ground @ _TYRE_BITS + self.on_stop @ _STOP_BITS
        return out


@dataclass(frozen=True)
class Suspension:
    """The full-car model, discretised at ``dt_s`` for every pattern of tyres on the ground
    and bump stops met.

    ``A``, ``B`` (256, 14, 14), (256, 14, 11): continuous systems, numbered as
    :data:`N_PATTERNS` says; ``Ad``, ``Bd`` the same discretised, each pattern on its first
    use (:meth:`discrete`: a drive meets a few dozen of the 256, and each costs a matrix
    exponential). The common system (all tyres down, no stop met) also in modal form,
    ``z[k+1] = lam z[k] + Bm u[k]`` with ``x = V z``.
    """

    A: FloatArray
    B: FloatArray
    Ad: FloatArray
    Bd: FloatArray
    discretised: NDArray[np.bool_]  # (256,): which patterns Ad and Bd hold yet
    lam: NDArray[np.complex128]  # (14,)
    V: NDArray[np.complex128]  # (14, 14)
    Vinv: NDArray[np.complex128]  # (14, 14)
    Bm: NDArray[np.complex128]  # (14, 11)
    static_load_n: FloatArray  # (4,)
    tyre_n_per_m: float
    tyre_damping_ns_per_m: float
    unsprung_mass_kg: float
    corner_from_body: FloatArray  # (4, 3): zc = G (zs, theta, phi)
    stop_clearance_m: float
    dt_s: float

    @classmethod
    def build(cls, params: VehicleParams, dt_s: float) -> Suspension:
        A = np.empty((N_PATTERNS, N_STATES, N_STATES))
        B = np.empty((N_PATTERNS, N_STATES, N_INPUTS))
        Ad = np.full_like(A, np.nan)
        Bd = np.full_like(B, np.nan)
        discretised = np.zeros(N_PATTERNS, dtype=bool)
        for pattern in range(N_PATTERNS):
            down = tuple(bool(pattern >> i & 1) for i in range(4))
            stop = tuple(bool(pattern >> (4 + i) & 1) for i in range(4))
            A[pattern], B[pattern] = full_car_matrices(params, down, stop)  # type: ignore[arg-type]
        Ad[ALL_DOWN], Bd[ALL_DOWN] = _zoh(A[ALL_DOWN], B[ALL_DOWN], dt_s)
        discretised[ALL_DOWN] = True
        lam, V = np.linalg.eig(Ad[ALL_DOWN])
        Vinv = np.linalg.inv(V)
        xi, yi = params.corners()
        return cls(
            A=A,
            B=B,
            Ad=Ad,
            Bd=Bd,
            discretised=discretised,
            lam=lam,
            V=V,
            Vinv=Vinv,
            Bm=Vinv @ Bd[ALL_DOWN],
            static_load_n=params.static_wheel_load_n(),
            tyre_n_per_m=params.tyre_n_per_m,
            tyre_damping_ns_per_m=params.tyre_damping_ns_per_m,
            unsprung_mass_kg=params.unsprung_mass_kg,
            corner_from_body=np.stack([np.ones(4), -xi, yi], axis=1),
            stop_clearance_m=params.bump_stop_clearance_m,
            dt_s=dt_s,
        )

    def discrete(self, pattern: int) -> tuple[FloatArray, FloatArray]:
        """``Ad``, ``Bd`` of one contact pattern, discretised now if not yet."""
        if not self.discretised[pattern]:
            self.Ad[pattern], self.Bd[pattern] = _zoh(self.A[pattern], self.B[pattern], self.dt_s)
            self.discretised[pattern] = True
        return self.Ad[pattern], self.Bd[pattern]

    def equilibrium(self, u: FloatArray) -> FloatArray:
        """The static state for constant input ``u`` (11,), all tyres down: ``A x + B u = 0``."""
        x: FloatArray = np.linalg.solve(self.A[ALL_DOWN], -self.B[ALL_DOWN] @ u)
        return x

    def contact_force(self, states: FloatArray, u: FloatArray) -> FloatArray:
        """The force each tyre would push with if it were on the ground, (n, 4) N:
        ``W_i + kt (r_i - zu_i) + ct (r_i' - zu_i')``. Negative means it would pull."""
        return (
            self.static_load_n
            + self.tyre_n_per_m * (u[:, INPUT_ROAD] - states[:, 3:7])
            + self.tyre_damping_ns_per_m * (u[:, INPUT_ROAD_RATE] - states[:, 10:14])
        )

    def compression(self, states: FloatArray) -> FloatArray:
        """Each corner's travel up from static ride height, ``zu_i - zc_i``, (n, 4) m."""
        out: FloatArray = states[:, 3:7] - states[:, :3] @ self.corner_from_body.T
        return out

    def step_modal(self, x0: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """All tyres down, no stop met: advance from ``x0`` (14,) through inputs ``u``
        (n, 11) mode by mode.

        Returns the states at the start of each sample (n, 14) and after the last (14,).
        """
        z0 = self.Vinv @ x0.astype(np.complex128)
        drive = u @ self.Bm.T  # (n, 14)
        n = u.shape[0]
        z = np.empty((n + 1, N_STATES), dtype=np.complex128)
        z[0] = z0
        for m in range(N_STATES):
            # y[k] = lam y[k-1] + drive[k], y[-1] = z0  ->  y[k] = z[k+1]
            z[1:, m], _ = lfilter([1.0], [1.0, -self.lam[m]], drive[:, m], zi=[self.lam[m] * z0[m]])
        states = (z @ self.V.T).real
        return states[:-1], states[-1]

    def step_switched(
        self,
        x0: FloatArray,
        u: FloatArray,
        out: FloatArray | None = None,
        on_ground: NDArray[np.bool_] | None = None,
        on_stop: NDArray[np.bool_] | None = None,
    ) -> FloatArray:
        """One dynamics step at a time, each with the discrete system of the tyres on the
        ground and the bump stops met during it.

        A tyre is on the ground for a step when it pushes (``contact_force >= 0``) both at
        the step's start and at its end (under the step's held input). So it leaves the
        ground at the step in which its force would cross zero rather than pulling until the
        next step, and lands at the first step that starts with it pressed into the road:
        it never pulls, and at worst pushes for up to one step (1 ms) less than it would.
        A bump stop is met for a step when the corner starts it beyond the clearance (a
        stop, too, only ever pushes: it is met at most one step late and left at most one
        step late, by travel of under a millimetre at the 1 m/s a hard hit reaches).

        Returns the end state (14,); the states at the start of each sample go into ``out``
        (n, 14), which tyres were down and which stops met during each step into
        ``on_ground`` and ``on_stop`` (n, 4) when given.
        """
        n = u.shape[0]
        kt, ct = self.tyre_n_per_m, self.tyre_damping_ns_per_m
        pre = self.static_load_n + kt * u[:, INPUT_ROAD] + ct * u[:, INPUT_ROAD_RATE]  # (n, 4)
        G = self.corner_from_body
        clearance = self.stop_clearance_m
        x = np.array(x0, dtype=np.float64)
        for k in range(n):
            if out is not None:
                out[k] = x
            down = pre[k] - kt * x[3:7] - ct * x[10:14] >= 0.0
            stops = x[3:7] - G @ x[:3] > clearance
            while True:
                pattern = _pattern(down, stops)
                Ad, Bd = self.discrete(pattern)
                x_next = Ad @ x + Bd @ u[k]
                pulls = down & (pre[k] - kt * x_next[3:7] - ct * x_next[10:14] < 0.0)
                if not pulls.any():
                    break
                down &= ~pulls
            if on_ground is not None:
                on_ground[k] = down
            if on_stop is not None:
                on_stop[k] = stops
            x = x_next
        return x

    def step_block(self, x0: FloatArray, u: FloatArray) -> SuspensionBlock:
        """Advance from ``x0`` (14,) through inputs ``u`` (n, 11), tyres and stops unilateral.

        The modal path first; if any tyre would pull at the start or the end of some step,
        or a corner starts a step beyond its bump stop's clearance, everything from that
        step on is redone step by step (:meth:`step_switched`).
        """
        n = u.shape[0]
        states, end = self.step_modal(x0, u)
        after = np.concatenate([states[1:], end[None, :]])
        leaves = (self.contact_force(states, u) < 0.0) | (self.contact_force(after, u) < 0.0)
        leaves |= self.compression(states) > self.stop_clearance_m
        switching = np.flatnonzero(leaves.any(axis=1))
        on_ground = np.ones((n, 4), dtype=bool)
        on_stop = np.zeros((n, 4), dtype=bool)
        stepped = 0
        if switching.size:
            k0 = int(switching[0])
            states = states.copy()
            end = self.step_switched(
                states[k0],
                u[k0:],
                out=states[k0:],
                on_ground=on_ground[k0:],
                on_stop=on_stop[k0:],
            )
            stepped = n - k0
        force = np.where(on_ground, self.contact_force(states, u), 0.0)
        return SuspensionBlock(
            states=states,
            end=end,
            tyre_force_n=np.maximum(force, 0.0),
            on_ground=on_ground,
            on_stop=on_stop,
            stepped=stepped,
        )

    def accelerations(self, block: SuspensionBlock, u: FloatArray) -> FloatArray:
        """Second derivatives of the 7 coordinates, (n, 7): ``x' = A x + B u`` with each
        sample's own system (the tyres that were down, the stops that were met)."""
        p = block.patterns
        common = p == ALL_DOWN
        A, B = self.A[ALL_DOWN], self.B[ALL_DOWN]
        acc: FloatArray = block.states @ A[7:].T + u @ B[7:].T
        if not common.all():
            rows = np.flatnonzero(~common)
            acc[rows] = np.einsum(
                "kij,kj->ki", self.A[p[rows], 7:], block.states[rows]
            ) + np.einsum("kij,kj->ki", self.B[p[rows], 7:], u[rows])
        return acc

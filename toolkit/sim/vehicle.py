"""The simulated vehicle: geometry, tyres, suspension dynamics and the race's speed controller.

Frames: ``base_link`` has x forward, y left, z up, its origin on the ground below the centre
of the rear axle (at static equilibrium on flat ground). Pitch is positive nose-down and roll
positive left-side-up (right-handed rotations about y and x). Tyres and corners are ordered
FL, FR, RL, RR throughout.

**Suspension.** The classic 7-degree-of-freedom full-car model (Gillespie 1992, ch. 5; Wong
2001, ch. 7): body heave ``zs``, pitch ``theta`` and roll ``phi`` on four spring-damper
corners, each over an unsprung wheel mass ``zu_i`` on a tyre. Forces are deviations from the
static equilibrium on flat ground, where gravity, the springs' preload and the static wheel
loads ``W_i`` cancel::

    F_i  = ks (zu_i - zc_i) + cs (zu_i' - zc_i')               zc_i = zs - x_i theta + y_i phi
    T_i  = max(0, W_i + kt (r_i - zu_i) + ct (r_i' - zu_i'))   total tyre force, never a pull
    ms zs''    =  sum F_i
    Iy theta'' = -sum x_i F_i - ms h a_x                       (squat under acceleration)
    Ix phi''   =  sum y_i F_i + ms h a_y                       (body roll in turns)
    mu zu_i''  = -F_i + T_i - W_i

with ``x_i, y_i`` the corner's position relative to the centre of gravity and ``r_i`` the
tyre's *effective* road height (below). While a tyre pushes (``T_i > 0``) its row is the
linear model; when it would pull, the wheel leaves the ground and only its weight and the
spring's preload act on it (``T_i - W_i = -W_i``) until it lands again. Heights are absolute
(the road includes the hills), so the body follows the terrain's slope and the pitch and roll
it produces are the vehicle's true attitude.

**Tyres.** A tyre is not a point: it has a footprint about as long as wide, and its round
outline reaches ahead of and behind it, so it bridges holes shorter than the footprint, is
lifted by the top of a rock and starts to climb an edge before its centre gets there (the
*enveloping* of short obstacles: Gillespie 1992, ch. 5 "Tire/wheel assembly"; Zegelaar 1998;
Schmeitz 2004; Pacejka 2006, ch. 10). :class:`TyreFootprint` turns the road under the whole
footprint into the one *effective road height* ``r_i`` that the vertical dynamics see, as the
effective-road-input models of Schmeitz & Pacejka do. It is computed from geometry at the
static wheel load, not from the instantaneous load, which keeps the dynamics linear between
contact changes.

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
J. Y. Wong, *Theory of Ground Vehicles*, 3rd ed., Wiley 2001, ch. 7 (vehicle ride); P. W. A.
Zegelaar, *The dynamic response of tyres to brake torque variations and road unevennesses*,
PhD thesis, TU Delft 1998; A. J. C. Schmeitz, *A semi-empirical three-dimensional model of the
pneumatic tyre rolling over arbitrarily uneven road surfaces*, PhD thesis, TU Delft 2004;
H. B. Pacejka, *Tyre and Vehicle Dynamics*, 2nd ed., Butterworth-Heinemann 2006, ch. 10;
D. C. Davis, "A radial-spring terrain-enveloping tire model", *Vehicle System Dynamics* 4
(1975).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.signal import lfilter

FloatArray = NDArray[np.floating[Any]]

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class VehicleParams:
    """A VW Touareg like Stanley, set up as a desert race SUV. SI units: m, kg, kg m^2, N/m,
    N s/m, Pa.

    Body and geometry: Stanley is a stock-bodied 2004 Touareg R5 (2.855 m wheelbase, 1.65 m
    track) with about 2.2 t sprung including its equipment; unchanged from the first model.

    Suspension and tyres. Modes of the whole model (:func:`modal_summary`, eigenvalues of the
    full car): heave 1.13 Hz at a damping ratio of 0.26, pitch 1.25 Hz at 0.29, roll 1.53 Hz
    at 0.35, wheel hop 12.4-12.7 Hz at 0.29-0.30.

    * ``spring_n_per_m`` 30 kN/m at each wheel: body bounce near 1.1 Hz, at the soft end of
      the 1-1.5 Hz that Gillespie (1992, ch. 5) gives for cars, as off-road vehicles are set
      up for travel rather than body control.
    * ``body_damping_ratio`` 0.30: ``cs / (2 sqrt(ks ms / 4))``, Gillespie's quarter-car
      damping ratio (1992, ch. 5), whose range for modern cars he gives as 0.2-0.4; Wong
      (2001, ch. 7) shows the same range as the compromise between ride and road holding.
      The first model's 4500 N s/m was 0.5, about twice typical (issue 11). In the lower half
      of the range because the damper also damps wheel hop: at the hop frequency ``w_u`` the
      body's acceleration is about ``kt r / ms`` whatever the damping, against about
      ``cs w r / ms`` between the two modes, so on a road whose velocity spectrum is flat
      (ISO 8608) the hop peak stands above the floor only while ``cs < kt / w_u``, about
      ``sqrt(kt mu)`` (here 2.4 kN s/m against 4.0-4.2). Not at its bottom, 0.2-0.25: a wheel
      hop damped to 0.23 rings for several cycles over washboard near its frequency, which
      made the labels hang on where the shock filter's band starts (tuned on race seeds
      601-606, ``benchmarks/sim_seeds.py``; see benchmarks/README.md).
    * ``unsprung_mass_kg`` 55 kg per corner: wheel and tyre (about 25 kg for an 18 inch alloy
      with a 255/55 tyre), brake, aluminium hub carrier and half of the (aluminium) links,
      spring and drive shaft of a heavy SUV; 10 % of the corner's 550 kg sprung mass, the
      tenth Gillespie (1992, ch. 5) takes as typical.
    * ``tyre_n_per_m`` 320 kN/m: the vertical rate of a large SUV radial (extra-load 255/55
      R18). Car tyres are about 150-300 kN/m, the rate growing with size and pressure
      (Pacejka 2006, ch. 10; Wong 2001, ch. 1); a light-truck-sized, extra-load tyre is a
      little above that range. An estimate, not a measurement. With the spring it puts wheel
      hop at ``sqrt((ks + kt) / mu) / 2 pi`` = 12.7 Hz, inside the 10-15 Hz that Gillespie
      (1992, ch. 5) gives for wheel hop, and clear of the shock filter's 10 Hz band edge.
    * ``tyre_damping_ns_per_m`` 100 N s/m: a rolling radial tyre damps little, far less than
      the damper (Wong 2001, ch. 1, on the tyre's vertical damping falling with speed); about
      1 % of critical for the wheel-hop mode.
    * ``wheel_radius_m`` 0.38 m: a 255/55 R18 (the Touareg's size) is 0.369 m unloaded, a
      255/60 R18 0.382 m.
    * ``tyre_width_m`` 0.22 m: the tread's contact width, about 85 % of the 255 mm section
      width (the bulging sidewalls are not in contact).
    * ``tyre_pressure_pa`` 200 kPa (29 psi): a little under road pressure (about 240 kPa), as
      desert drivers air down. The print's mean ground pressure is the inflation pressure
      plus a small carcass term (Wong 2001, ch. 2, for a tyre on firm ground), so the print
      is ``W / (p b)`` = 0.128 m (front) and 0.141 m (rear) long.
    * ``bump_stop_clearance_m`` 0.045 m: the wheel's travel up from static ride height until
      the jounce bumper on the damper rod is met. Gillespie (1992, ch. 5) takes about
      +-0.1 m as the "rattle space" of a car suspension, of which the bumper's free travel is
      the larger part; Stanley rode low, with some 200 kg of computers, sensors and rack on a
      stock Touareg, so less than half of that is left (judgement, not a measurement).
    * ``bump_stop_n_per_m`` 300 kN/m: the jounce bumper's rate once met, ten times the
      spring's. Micro-cellular polyurethane bumpers stiffen progressively from about the
      spring's rate to many times it over their 20-40 mm of crush (Gillespie 1992, ch. 5,
      on bump stops as progressive springs; the tenfold linear rate is judgement). This is
      where a hard hit comes from: within the clearance the soft spring and damper filter
      the road, beyond it the wheel's motion goes nearly straight into the body.
    """

    wheelbase_m: float = 2.855
    track_m: float = 1.65
    cg_from_rear_m: float = 1.35
    cg_height_m: float = 0.75
    sprung_mass_kg: float = 2200.0
    pitch_inertia_kgm2: float = 3800.0
    roll_inertia_kgm2: float = 850.0
    unsprung_mass_kg: float = 55.0
    spring_n_per_m: float = 30000.0
    body_damping_ratio: float = 0.30
    tyre_n_per_m: float = 320000.0
    tyre_damping_ns_per_m: float = 100.0
    wheel_radius_m: float = 0.38
    tyre_width_m: float = 0.22
    tyre_pressure_pa: float = 200e3
    bump_stop_clearance_m: float = 0.045
    bump_stop_n_per_m: float = 300000.0

    @property
    def damper_ns_per_m(self) -> float:
        """Damper rate per corner: ``cs = 2 zeta sqrt(ks ms / 4)`` (Gillespie's quarter car,
        its body on the suspension spring)."""
        return (
            2.0
            * self.body_damping_ratio
            * float(np.sqrt(self.spring_n_per_m * self.sprung_mass_kg / 4.0))
        )

    def corners(self) -> tuple[FloatArray, FloatArray]:
        """Corner positions relative to the CG, order FL, FR, RL, RR: (x_m, y_m), each (4,)."""
        a = self.wheelbase_m - self.cg_from_rear_m
        b = self.cg_from_rear_m
        h = self.track_m / 2
        return np.array([a, a, -b, -b]), np.array([h, -h, h, -h])

    def print_length_m(self) -> FloatArray:
        """Length of each tyre's print on flat ground at its static load, (4,) m: the print's
        mean ground pressure is about the inflation pressure, ``L = W / (p b)``."""
        return self.static_wheel_load_n() / (self.tyre_pressure_pa * self.tyre_width_m)

    def static_wheel_load_n(self) -> FloatArray:
        """Static load on each tyre on flat ground, (4,) N: the body's weight split between
        the axles by the CG's position, half to each side, plus the wheel's own weight."""
        a = self.wheelbase_m - self.cg_from_rear_m
        front = self.sprung_mass_kg * self.cg_from_rear_m / self.wheelbase_m / 2.0
        rear = self.sprung_mass_kg * a / self.wheelbase_m / 2.0
        sprung = np.array([front, front, rear, rear])
        return (sprung + self.unsprung_mass_kg) * GRAVITY_MPS2


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


# --------------------------------------------------------------------------------------------
# Tyre footprint: the effective road height

# Where the footprint samples the road (m, along the wheel from the contact centre). The
# print itself is about 0.13-0.14 m long: 2 cm steps there. Beyond it the round outline only
# meets what stands above the road, so 4 cm steps, out to where the tread is 0.21 m above its
# lowest point, higher than the tallest feature (0.15 m) on top of the roughness.
FOOTPRINT_X_M = np.concatenate(
    [-np.arange(0.34, 0.13, -0.04), np.arange(-0.10, 0.1001, 0.02), np.arange(0.14, 0.35, 0.04)]
)
FOOTPRINT_RIBS = 4  # across the tread: 5.5 cm apart, about the terrain grid's 5 cm


@dataclass(frozen=True)
class TyreFootprint:
    """Where each tyre samples the road, and the effective road height it makes of it.

    The tyre is a bed of independent springs, uniform per unit area, under a rigid tread of
    the tyre's round outline (the radial-spring tyre of Davis 1975 in its small-angle form;
    Gillespie 1992, ch. 5): ``m`` cells, ``FOOTPRINT_RIBS`` ribs across ``tyre_width_m`` by the
    ``FOOTPRINT_X_M`` stations along the wheel, cell ``j`` of weight ``w_j`` (its length along
    the wheel). The undeformed tread at ``x`` ahead of the contact centre is ``e(x) = R -
    sqrt(R^2 - x^2)`` above its lowest point. On flat ground the bed is pressed in by ``d_i``,
    so that the print it makes, ``2 sqrt(2 R d_i)`` long, is the tyre's real print at the
    static load: ``L_i = W_i / (p b)`` (:meth:`VehicleParams.print_length_m`). The rest of the
    tyre's deflection is the carcass's, in series, and belongs to the tyre spring ``kt``. On a
    road of heights ``h_j`` the tread's lowest point settles at the height ``z`` where the bed
    carries the same load as on flat ground::

        sum_j w_j max(0, h_j - e_j - z) = V_i,        V_i = sum_j w_j max(0, d_i - e_j)

    and the effective road height is ``r_i = z + d_i``: exactly ``h`` on flat ground, the mean
    height under the print on gentle roughness. A hole narrower or shorter than the footprint
    leaves the cells over it unloaded and is partly bridged (the tread sinks until its outline
    meets the rims); a rock carries the load on its top and lifts the tyre by nearly its full
    height; an edge is felt from where the round outline first touches it. Like the
    tandem-cam effective road of Schmeitz (2004) the result depends on the road's geometry
    only, not on the instantaneous load, so the dynamics stay linear.

    Arrays: ``forward_m``, ``lateral_m``, ``lift_m``, ``weight`` (m,) per cell, in the wheel's
    frame (x along its heading, y left of the contact centre); ``bed_deflection_m`` and
    ``bed_volume_m`` (4,) per tyre.
    """

    forward_m: FloatArray
    lateral_m: FloatArray
    lift_m: FloatArray
    weight: FloatArray
    bed_deflection_m: FloatArray
    bed_volume_m: FloatArray

    @classmethod
    def build(cls, p: VehicleParams) -> TyreFootprint:
        x = FOOTPRINT_X_M
        # Each station stands for the stretch half-way to its neighbours.
        edges = np.concatenate([[x[0]], 0.5 * (x[1:] + x[:-1]), [x[-1]]])
        length = np.diff(edges)
        rib = p.tyre_width_m / FOOTPRINT_RIBS
        y = (np.arange(FOOTPRINT_RIBS) - (FOOTPRINT_RIBS - 1) / 2) * rib
        xx, yy = np.meshgrid(x, y, indexing="ij")
        weight = np.repeat(length, FOOTPRINT_RIBS)
        r = p.wheel_radius_m
        lift = r - np.sqrt(r**2 - xx.ravel() ** 2)
        d = (p.print_length_m() / 2) ** 2 / (2 * r)
        volume = (weight * np.maximum(d[:, None] - lift[None, :], 0.0)).sum(axis=1)
        return cls(
            forward_m=xx.ravel(),
            lateral_m=yy.ravel(),
            lift_m=lift,
            weight=weight,
            bed_deflection_m=d,
            bed_volume_m=volume,
        )

    @property
    def cells(self) -> int:
        return int(self.lift_m.size)

    def effective_height(self, heights_m: FloatArray) -> FloatArray:
        """Effective road height of each tyre, (n, 4), from the road under its cells,
        ``heights_m`` (n, 4, m).

        ``g(z) = sum_j w_j max(0, c_j - z) - V`` with ``c_j = h_j - e_j`` is convex, piecewise
        linear and falling, so Newton's method solves it exactly in a few steps: from any
        start with a cell above it, the first step lands at or left of the root, and from
        the left each step ``z += g(z) / W(z)`` (``W`` the weight of the cells in contact)
        stays left of it and ends on it once the set of cells in contact is right. The start
        assumes the cells in contact on flat ground, which is the root on flat ground.
        """
        c = heights_m - self.lift_m
        w = self.weight
        flat = (self.lift_m < self.bed_deflection_m[:, None]) * w  # (4, m)
        z = (np.einsum("ntm,tm->nt", c, flat) - self.bed_volume_m) / flat.sum(axis=1)
        for _ in range(c.shape[-1] + 1):  # at most one step per cell taken into contact
            pressed = c - z[..., None]
            np.maximum(pressed, 0.0, out=pressed)
            step = (pressed @ w - self.bed_volume_m) / ((pressed > 0.0) @ w)
            z += step
            if np.abs(step).max() <= 1e-12:
                break
        out: FloatArray = z + self.bed_deflection_m
        return out


# --------------------------------------------------------------------------------------------
# Suspension dynamics

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

"""The simulated vehicle's parameters: a VW Touareg like Stanley, set up as a desert race SUV.

Frames: ``base_link`` has x forward, y left, z up, its origin on the ground below the centre
of the rear axle (at static equilibrium on flat ground). Pitch is positive nose-down and roll
positive left-side-up (right-handed rotations about y and x). Tyres and corners are ordered
FL, FR, RL, RR throughout.

The model built from them: the full-car suspension in :mod:`toolkit.sim.suspension`, the
enveloping tyre in :mod:`toolkit.sim.tyre`, the race's speed controller in
:mod:`toolkit.sim.speed_control`.

References: T. D. Gillespie, *Fundamentals of Vehicle Dynamics*, SAE 1992, ch. 5 (ride);
J. Y. Wong, *Theory of Ground Vehicles*, 3rd ed., Wiley 2001, ch. 1, 2, 7 (tyres, vehicle
ride); H. B. Pacejka, *Tyre and Vehicle Dynamics*, 2nd ed., Butterworth-Heinemann 2006, ch. 10.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class VehicleParams:
    """A VW Touareg like Stanley, set up as a desert race SUV. SI units: m, kg, kg m^2, N/m,
    N s/m, Pa.

    Body and geometry: Stanley is a stock-bodied 2004 Touareg R5 (2.855 m wheelbase, 1.65 m
    track) with about 2.2 t sprung including its equipment; unchanged from the first model.

    Suspension and tyres. Modes of the whole model
    (:func:`~toolkit.sim.suspension.modal_summary`, eigenvalues of the full car): heave
    1.13 Hz at a damping ratio of 0.26, pitch 1.25 Hz at 0.29, roll 1.53 Hz at 0.35, wheel
    hop 12.4-12.7 Hz at 0.29-0.30.

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

"""The tyre's footprint: the one *effective road height* the vertical dynamics see.

A tyre is not a point: it has a footprint about as long as wide, and its round outline
reaches ahead of and behind it, so it bridges holes shorter than the footprint, is lifted by
the top of a rock and starts to climb an edge before its centre gets there (the *enveloping*
of short obstacles: Gillespie 1992, ch. 5 "Tire/wheel assembly"; Zegelaar 1998; Schmeitz
2004; Pacejka 2006, ch. 10). :class:`TyreFootprint` turns the road under the whole footprint
into the one effective road height ``r_i`` that the suspension (:mod:`toolkit.sim.suspension`)
sees, as the effective-road-input models of Schmeitz & Pacejka do. It is computed from
geometry at the static wheel load, not from the instantaneous load, which keeps the dynamics
linear between contact changes.

References: P. W. A. Zegelaar, *The dynamic response of tyres to brake torque variations and
road unevennesses*, PhD thesis, TU Delft 1998; A. J. C. Schmeitz, *A semi-empirical
three-dimensional model of the pneumatic tyre rolling over arbitrarily uneven road
surfaces*, PhD thesis, TU Delft 2004; H. B. Pacejka, *Tyre and Vehicle Dynamics*, 2nd ed.,
Butterworth-Heinemann 2006, ch. 10; D. C. Davis, "A radial-spring terrain-enveloping tire
model", *Vehicle System Dynamics* 4 (1975).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.vehicle import VehicleParams

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

"""The route's centreline: gentle curves, hills and speed-limit segments, in ENU.

Route coordinates ``(s, d)``: ``s`` horizontal distance along the centreline (m), ``d`` the
lateral offset from it (m, left positive). The centreline is integrated from a curvature
``kappa(s)`` and a grade ``g(s)``, each a sum of long-wavelength sinusoids; see
:func:`make_route`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray

if TYPE_CHECKING:
    from toolkit.sim.world_params import WorldParams


@dataclass(frozen=True)
class Route:
    """The route's centreline, sampled every ``ds_m`` metres of horizontal distance.

    Arrays have shape (n,): ``s_m`` distance, ``x_m``/``y_m`` ENU position, ``heading_rad``
    (counter-clockwise from east), ``curvature_per_m`` (left turns positive), ``z0_m`` the
    centreline elevation and ``speed_limit_mps`` the segment's speed limit.
    """

    s_m: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    curvature_per_m: FloatArray
    z0_m: FloatArray
    speed_limit_mps: FloatArray

    @property
    def ds_m(self) -> float:
        return float(self.s_m[1] - self.s_m[0])

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1])

    def sample(self, s_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Centreline (x, y, heading) at distances ``s_m``, any shape; linear between samples
        and clamped at the ends. The samples are uniform, so no search is needed."""
        u = np.asarray(s_m, dtype=np.float64) * (1.0 / self.ds_m)
        np.minimum(np.maximum(u, 0.0, out=u), self.s_m.size - 1.000001, out=u)  # np.clip
        i = u.astype(np.intp)
        f = u - i
        x = self.x_m[i] + f * self._dx[i]
        y = self.y_m[i] + f * self._dy[i]
        heading = self.heading_rad[i] + f * self._dh[i]
        return x, y, heading

    @property
    def _dx(self) -> FloatArray:
        return self._diffs()[0]

    @property
    def _dy(self) -> FloatArray:
        return self._diffs()[1]

    @property
    def _dh(self) -> FloatArray:
        return self._diffs()[2]

    def _diffs(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        cached = self.__dict__.get("_diff_cache")
        if cached is None:
            cached = tuple(
                np.append(np.diff(a), 0.0) for a in (self.x_m, self.y_m, self.heading_rad)
            )
            object.__setattr__(self, "_diff_cache", cached)
        return cached

    def to_world(self, s_m: FloatArray, d_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Route coordinates to ENU (x, y)."""
        x, y, heading = self.sample(s_m)
        return x - d_m * np.sin(heading), y + d_m * np.cos(heading)

    def to_route(
        self, x_m: FloatArray, y_m: FloatArray, s_guess_m: FloatArray, iterations: int = 3
    ) -> tuple[FloatArray, FloatArray]:
        """ENU (x, y) to route coordinates, by Newton steps from a nearby ``s_guess_m``.

        Valid within a few tens of metres of the centreline, where the projection onto the
        centreline is unique (curvature radius is at least 180 m). Each step shrinks the
        error by a factor of about ``kappa * d`` (< 0.25), so 3 steps from a guess within
        tens of metres reach millimetres, and 2 suffice from a guess within a metre.
        """
        s = np.asarray(s_guess_m, dtype=np.float64)
        for _ in range(iterations):
            cx, cy, heading = self.sample(s)
            ex, ey = x_m - cx, y_m - cy
            s = s + ex * np.cos(heading) + ey * np.sin(heading)
        cx, cy, heading = self.sample(s)
        d = -(x_m - cx) * np.sin(heading) + (y_m - cy) * np.cos(heading)
        return s, d


def _smooth_noise(
    rng: np.random.Generator, n: int, ds_m: float, wavelengths_m: Sequence[float] | FloatArray
) -> FloatArray:
    """A sum of sinusoids with random phases and the given wavelengths, unit peak amplitude."""
    s = np.arange(n) * ds_m
    out = np.zeros(n)
    for wavelength in wavelengths_m:
        out += np.sin(2 * np.pi * s / wavelength + rng.uniform(0, 2 * np.pi)) * rng.uniform(0.5, 1)
    return out / max(len(wavelengths_m), 1)


def make_route(params: WorldParams, rng: np.random.Generator, ds_m: float = 1.0) -> Route:
    """Lay out a route of gentle curves, hills and speed-limit segments."""
    n = int(np.ceil(params.length_m / ds_m)) + 2
    s = np.arange(n) * ds_m
    curvature: FloatArray
    z0: FloatArray
    if params.straight:
        curvature = np.zeros(n)
        z0 = np.zeros(n)
    else:
        curvature = params.max_curvature_per_m * _smooth_noise(
            rng, n, ds_m, rng.uniform(250.0, 1500.0, size=4)
        )
        # Long straights between the bends, as on desert tracks.
        curvature *= np.clip(np.abs(_smooth_noise(rng, n, ds_m, [2000.0])) * 2.5, 0, 1)
        # Grade g(s) integrates to elevation; bounded by max_grade.
        grade = params.max_grade * _smooth_noise(rng, n, ds_m, rng.uniform(300.0, 2500.0, size=3))
        z0 = np.concatenate([[0.0], np.cumsum(0.5 * (grade[1:] + grade[:-1])) * ds_m])
    heading0 = rng.uniform(-np.pi, np.pi) if not params.straight else 0.0
    heading = heading0 + np.concatenate(
        [[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1])) * ds_m]
    )
    # Midpoint-rule integration keeps the centreline within millimetres of the exact curve.
    mid_heading = 0.5 * (heading[1:] + heading[:-1])
    x = np.concatenate([[0.0], np.cumsum(np.cos(mid_heading)) * ds_m])
    y = np.concatenate([[0.0], np.cumsum(np.sin(mid_heading)) * ds_m])
    # Segment speed limits between 5 and 17 m/s, each segment 200-800 m long.
    limits = np.empty(n)
    i = 0
    while i < n:
        seg = int(rng.uniform(200.0, 800.0) / ds_m)
        limits[i : i + seg] = rng.choice([8.0, 10.0, 12.0, 13.5, 15.0, 17.0])
        i += seg
    return Route(
        s_m=s,
        x_m=x,
        y_m=y,
        heading_rad=heading,
        curvature_per_m=curvature,
        z0_m=z0,
        speed_limit_mps=limits,
    )

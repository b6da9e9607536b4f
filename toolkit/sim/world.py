"""The simulated world: a desert route and the terrain it crosses, decided by ``(params, seed)``.

The world is described in *route coordinates* ``(s, d)``: ``s`` is horizontal distance along
the route's centreline in metres and ``d`` the lateral offset from it, left positive. The
height of the ground is the sum of

* a smooth part: the route's hills ``z0(s)`` (:mod:`toolkit.sim.route`) plus a cross profile
  ``crossfall(d)`` (a crowned road, shoulders and low graded berms beside it);
* fine random roughness on the road with an ISO 8608 displacement spectrum
  ``Gd(n) = Gd(n0) (n / n0)^-2`` with ``n0 = 0.1`` cycles/m (class D on the dirt road, E in
  rough stretches), synthesised on a 5 cm grid;
* coarser, rougher terrain beside the road on a 20 cm grid;
* sparse discrete rough features (washboard, potholes, rocks, ruts, cattle guards), placed
  across the road and its shoulders and sized from the distributions stated with the
  ``FEATURE_*`` constants (:mod:`toolkit.sim.features`).

The grids are generated lazily in tiles along ``s`` (:mod:`toolkit.sim.terrain`) from seeds
derived from the world seed and the tile index, so a 60-minute route costs no more memory than
a one-minute one and any part of the world can be regenerated on its own, bit for bit.
Neighbouring tiles are joined by a variance-preserving cross-fade, so the field has no seams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.sim.features import FEATURE_KINDS, RoughFeature, make_features
from toolkit.sim.route import Route, make_route
from toolkit.sim.terrain import Terrain


@dataclass(frozen=True)
class WorldParams:
    """Everything that decides the world, besides the seed.

    Lengths in metres. ``feature_rate_per_km`` is the mean number of discrete rough features
    per kilometre of road; ``rough_stretch_fraction`` the share of the road that is rougher
    (ISO class ``rough_class``) than the base ``road_class``.
    """

    length_m: float
    road_half_width_m: float = 3.5
    road_class: str = "D"
    # Rough stretches are ISO class E ("very poor"), four times class D's spectral density.
    # Class F (the first model's) over 15 % of the road had the wheels off the ground every
    # few metres, a road a racer would not drive at the route's 10-17 m/s; and its Gaussian
    # roughness, not features a laser could single out, made most of the rough labels.
    rough_class: str = "E"
    rough_stretch_fraction: float = 0.15
    offroad_class: str = "F"
    feature_rate_per_km: float = 6.0
    feature_kinds: tuple[str, ...] = FEATURE_KINDS
    feature_height_range_m: tuple[float, float] = (0.02, 0.15)
    max_curvature_per_m: float = 1.0 / 180.0
    max_grade: float = 0.05
    straight: bool = False
    # Fixed features (kind, s_center_m, height_m) placed in addition to random ones; the
    # calibration profile uses this for its obstacles.
    fixed_features: tuple[tuple[str, float, float], ...] = ()


@dataclass(frozen=True)
class World:
    """Route, terrain and features, all decided by ``(params, seed)``."""

    params: WorldParams
    seed: int
    route: Route
    terrain: Terrain

    @property
    def features(self) -> tuple[RoughFeature, ...]:
        return self.terrain.features


def make_world(params: WorldParams, seed: int) -> World:
    """Build the world for ``params`` and ``seed``; same inputs, same world, bit for bit."""
    route = make_route(params, np.random.default_rng([seed, 0]))
    features = make_features(params, route, np.random.default_rng([seed, 3]))
    terrain = Terrain(params=params, seed=seed, route=route, features=features)
    return World(params=params, seed=seed, route=route, terrain=terrain)

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

from toolkit.sim.features import RoughFeature, make_features
from toolkit.sim.route import Route, make_route
from toolkit.sim.terrain import Terrain
from toolkit.sim.world_params import WorldParams


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

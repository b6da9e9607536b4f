"""What decides the simulated world besides its seed (:class:`WorldParams`), and the kinds of
rough feature it holds.

A leaf: the route, the terrain and the features read these, and the world
(:mod:`toolkit.sim.world`) builds itself from all of them, so none of those modules needs
another's for its parameters (they once imported one another through ``world.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

#: The kinds of discrete rough feature on the road (:mod:`toolkit.sim.features` shapes them).
FEATURE_KINDS = ("washboard", "pothole", "rock", "rut", "cattle_guard")


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


__all__ = ["FEATURE_KINDS", "WorldParams"]

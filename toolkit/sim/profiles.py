"""Simulation profiles: what kind of log ``terrain sim --profile NAME`` writes.

* ``sample``: about a minute of driving on a road dense with rough features, for demos,
  the bundled sample log and quick tests.
* ``race``: the realistic case. Rough features are mostly small stones, so (with 1.4 m
  events) about 0.3-0.6 % of events reach 0.02 G/mph, as in the paper's Sect. 7.
* ``calibration``: a straight, smooth road with five identical obstacles, each driven over
  at a different constant speed (5 to 15 m/s), for the shock-versus-speed line of Fig. 5.
  Identical copies of one obstacle stand in for turning round and driving it again.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from toolkit.errors import SimulationError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.sim.lidar import LidarParams
from toolkit.sim.sensors import GpsParams, SensorParams
from toolkit.sim.speed_control import ReactiveSpeedParams
from toolkit.sim.vehicle import VehicleParams
from toolkit.sim.world_params import WorldParams

PROFILE_NAMES = ("sample", "race", "calibration")

# 2005-10-08 (the Grand Challenge) 15:00 UTC; a fixed epoch keeps logs reproducible.
RACE_DAY_START_NS = 1_128_783_600_000_000_000
# Near Primm, Nevada, on the 2005 route.
DESERT_ORIGIN = GeodeticOrigin(latitude_deg=35.61, longitude_deg=-115.39, altitude_m=800.0)

CALIBRATION_SPEEDS_MPS = (5.0, 7.5, 10.0, 12.5, 15.0)
CALIBRATION_SPACING_M = 220.0
CALIBRATION_FIRST_M = 200.0
CALIBRATION_OBSTACLE_HEIGHT_M = 0.08


@dataclass(frozen=True)
class SimProfile:
    """Everything the simulator needs besides the seed."""

    name: str
    world: WorldParams
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    controller: ReactiveSpeedParams = field(default_factory=ReactiveSpeedParams)
    start_time_ns: int = RACE_DAY_START_NS
    origin: GeodeticOrigin = DESERT_ORIGIN
    lane_wander_m: float = 0.3
    initial_speed_mps: float = 8.0
    # Speeds per stretch for the calibration runs: (s_from_m, speed_mps) pairs; empty means
    # the route's own segment limits.
    speed_schedule: tuple[tuple[float, float], ...] = ()
    # The spinning 3-D lidar (``terrain sim --lidar``); None: the 2-D lasers only. Not part
    # of ``sensors``, whose every field the ``terrain_sim`` record holds: a log without the
    # lidar keeps the record it always had.
    lidar: LidarParams | None = None


def make_profile(name: str, distance_m: float | None = None) -> SimProfile:
    """The named profile, its route ``distance_m`` long (a profile default if None)."""
    if name not in PROFILE_NAMES:
        raise SimulationError(f"unknown profile {name!r}; choose one of {', '.join(PROFILE_NAMES)}")
    if distance_m is not None and distance_m < 100.0:
        raise SimulationError(f"--distance-m must be at least 100 m, got {distance_m}")
    if name == "sample":
        return SimProfile(
            name=name,
            world=WorldParams(
                length_m=distance_m or 710.0,
                # Dense, so a minute holds a dozen rough events although about 40 % of the
                # features lie beside the wheels (toolkit.sim.features.make_features).
                feature_rate_per_km=150.0,
                feature_height_range_m=(0.06, 0.15),
                rough_stretch_fraction=0.25,
            ),
            # One GPS dropout for certain, so every sample log exercises the filter's coasting.
            sensors=replace(
                SensorParams(),
                gps=replace(
                    GpsParams(), dropouts_per_hour=30.0, scheduled_dropouts_s=((30.0, 5.0),)
                ),
            ),
        )
    if name == "race":
        return SimProfile(
            name=name,
            # 58 features per km (one per 17 m; stones the commonest kind, heights log-uniform
            # 3-15 cm; a third of all features beside the wheels): with the class E rough
            # stretches, about 0.3-0.4 % of 1.4 m events reach 0.02 G/mph on race seeds
            # 601-606 (benchmarks/README.md; Sect. 7: 0.36 and 0.44 %). Set with that rate in
            # view, as the feature shares in features.py were.
            world=WorldParams(length_m=distance_m or 8000.0, feature_rate_per_km=58.0),
            # Random dropouts as well, but one of 10 s for certain, so every race log checks
            # how far the pose drifts while it coasts.
            sensors=replace(
                SensorParams(), gps=replace(GpsParams(), scheduled_dropouts_s=((60.0, 10.0),))
            ),
        )
    n = len(CALIBRATION_SPEEDS_MPS)
    length = distance_m or CALIBRATION_FIRST_M + n * CALIBRATION_SPACING_M
    obstacles = tuple(
        ("ridge", CALIBRATION_FIRST_M + i * CALIBRATION_SPACING_M, CALIBRATION_OBSTACLE_HEIGHT_M)
        for i in range(n)
        if CALIBRATION_FIRST_M + i * CALIBRATION_SPACING_M < length - 30.0
    )
    schedule = tuple(
        (max(0.0, CALIBRATION_FIRST_M + (i - 1) * CALIBRATION_SPACING_M + 20.0), v)
        for i, v in enumerate(CALIBRATION_SPEEDS_MPS)
    )
    return SimProfile(
        name=name,
        world=WorldParams(
            length_m=length,
            road_class="B",
            rough_stretch_fraction=0.0,
            feature_rate_per_km=0.0,
            straight=True,
            fixed_features=obstacles,
        ),
        sensors=replace(SensorParams(), gps=replace(GpsParams(), dropouts_per_hour=0.0)),
        controller=replace(ReactiveSpeedParams(), enabled=False, accel_mps2=1.5),
        initial_speed_mps=CALIBRATION_SPEEDS_MPS[0],
        speed_schedule=schedule,
    )

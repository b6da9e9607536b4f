"""Discrete rough features (washboard, potholes, rocks, ruts, cattle guards, ridges): their
kinds, sizes, shapes and places across the road, the height each adds to the ground, and
their random placement along a route.

The distributions are stated with the ``FEATURE_*`` constants below, each with its source
or marked as judgement.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray

if TYPE_CHECKING:
    from toolkit.sim.route import Route
    from toolkit.sim.world_params import WorldParams


# Height (peak-to-peak, or depth) range of each kind, metres: washboard corrugations are
# shallow but periodic (0.5-2 cm: the corrugations of a graded road between gradings;
# judgement), ruts and cattle-guard decks are bounded by what traffic leaves.
# Pothole depths span the three depth classes of the unsurfaced-road pothole rating
# (TM 5-626, 1995, ch. 3, distress "Potholes": 1/2-2 in, 2-4 in, over 4 in; Eaton &
# Beaucham, CRREL SR 92-26, 1992); rock heights are judgement (what a 0.2-0.5 m desert
# stone shows above the ground), capped per rock by its footprint (see make_features).
FEATURE_HEIGHT_RANGE_M = {
    "washboard": (0.005, 0.02),
    "pothole": (0.03, 0.15),
    "rock": (0.03, 0.15),
    "rut": (0.02, 0.08),
    "cattle_guard": (0.03, 0.08),
}
# "ridge" is placed only on purpose (calibration obstacles), never at random.

# Share of the random features of each kind (normalised over ``WorldParams.feature_kinds``).
# Judgement: stones are the common discrete hazard of a desert road (most of them small:
# heights log-uniform), potholes the next; ruts form only where the surface is soft, and
# cattle guards sit only where a fence crosses the road (at 58 features per km in the race
# profile, 1.7 per km). Washboard is the common periodic hazard of any unsurfaced road with
# traffic (Skorseth & Selim, "Gravel Roads Maintenance and Design Manual", FHWA/SD LTAP
# 2000, ch. 1), but a stretch of it is one long, narrow-band excitation: its ripples are
# spaced by the speed of the traffic that made them over its wheels' hop frequency
# (Taberlet, Morris & McElwaine, Phys. Rev. Lett. 99, 068003, 2007), so a vehicle driven at
# a similar speed meets it near its own wheel hop, and near where the shock filter's band
# starts. At 25 % of the features and 6-30 m a stretch (the first model's, 9 % of the road)
# washboard made most positive labels and which of them were positive hung on that band
# edge. At 3 % and 3-12 m a stretch (about 1 % of the road; corrugations gather where
# traffic brakes and accelerates, Skorseth & Selim ch. 1) the positives come mostly from
# discrete impacts, the paper's "small discontinuities" (sect. 8). The shares were set with
# the label rate measured on race seeds 601-606 (benchmarks/sim_seeds.py;
# benchmarks/README.md), not taken from a survey.
FEATURE_KIND_WEIGHTS = {
    "washboard": 0.03,
    "pothole": 0.31,
    "rock": 0.53,
    "rut": 0.10,
    "cattle_guard": 0.03,
}

# -- Where features lie across the road (d, left positive) --------------------------------
# Shoulder width beyond each road edge on which features may lie, metres: the graded
# shoulder and ditch of the cross profile (``Terrain.crossfall``: ditch from the edge to
# 0.8 m beyond, berm foot at 1.3 m). Judgement, to match that profile.
FEATURE_SHOULDER_WIDTH_M = 1.2
# Traffic's wheel paths lie at +-track/2 about the crown: a desert road carries too little
# traffic for lanes, so vehicles drive its crown and move over only to pass (judgement; it
# is also where the simulated vehicle drives). Lateral spread of traffic about them, metres:
# the AASHTO Mechanistic-Empirical Pavement Design Guide's default traffic wander is a
# standard deviation of 10 in (0.254 m) on a marked lane; an unmarked road is wandered a
# little more widely (judgement: 0.3 m).
FEATURE_WHEEL_PATH_SIGMA_M = 0.3
# Share of potholes centred in a wheel path (normal about it, sigma above); the rest are
# uniform over the road's width. Potholes need water and traffic together (TM 5-626 ch. 3;
# Skorseth & Selim ch. 1: water ponding in wheel-path depressions is worked into holes by
# wheels), so they concentrate in the wheel paths but also form wherever the crown is lost
# and water stands; the shoulders carry no traffic and get none. The 60/40 split is
# judgement.
FEATURE_POTHOLE_WHEEL_PATH_SHARE = 0.6
# Rocks come in three kinds of place, with judgement shares:
# * in a wheel path (as potholes there), FEATURE_ROCK_WHEEL_PATH_SHARE: stones of the
#   roadbed laid bare where traffic whips the fines out of the wheel paths (Skorseth & Selim
#   ch. 1, "loss of fines" and loose aggregate in the travelled way);
# * at the edges, FEATURE_ROCK_EDGE_SHARE: uniform in |d| over the band from
#   FEATURE_ROCK_EDGE_INSET_M inside each edge to the shoulder's outer side, where traffic
#   throws loose stone and graders leave it (Skorseth & Selim ch. 1: traffic displaces
#   surface gravel to the shoulder, and windrows form along it);
# * the rest uniform over road and shoulders: stones fallen from banks and loads, or
#   scattered by traffic.
FEATURE_ROCK_WHEEL_PATH_SHARE = 0.3
FEATURE_ROCK_EDGE_SHARE = 0.4
FEATURE_ROCK_EDGE_INSET_M = 0.5

# -- Sizes and shapes ------------------------------------------------------------------------
# Rocks: long horizontal axis log-uniform over 0.2-0.5 m (issue 11: desert rocks 0.2-0.5 m
# across; log-uniform because small stones outnumber large ones); short horizontal axis a
# uniform fraction of it (Zingg's b/a shape ratio, judgement: natural clasts mostly 0.5-1);
# orientation uniform. A rock rests on its largest face, so its shortest axis is vertical
# and its exposed height is at most its short horizontal axis: heights are drawn from the
# kind's range capped at that axis. Shape: the upper half of an ellipsoid, so its flanks
# are vertical at the footprint's edge (a tyre meets a step, then rolls over a dome).
FEATURE_ROCK_MAJOR_AXIS_RANGE_M = (0.2, 0.5)
FEATURE_ROCK_AXIS_RATIO_RANGE = (0.5, 1.0)
# Potholes: long axis log-uniform over 0.3-1.2 m, spanning TM 5-626's diameter classes
# (< 1 ft, 1-2 ft, 2-3 ft, > 3 ft; ASTM D6433 for paved roads: "usually less than 750 mm");
# short axis 0.6-1 of it (near-round, a little longer than wide); orientation uniform; depth
# drawn independently from the kind's range, so potholes are wider and, for their width,
# shallower than rocks. Shape: a vertical wall at the rim down to
# FEATURE_POTHOLE_WALL_FRACTION of the depth ("sharp edges and vertical sides near the top
# of the hole", ASTM D6433's pothole definition), then a rounded (paraboloid) bowl to the
# full depth at the centre. The wall fraction is judgement.
FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M = (0.3, 1.2)
FEATURE_POTHOLE_AXIS_RATIO_RANGE = (0.6, 1.0)
FEATURE_POTHOLE_WALL_FRACTION = 0.5
# Length along the road of the features placed by hand (the calibration profile's ridges), m:
# a 1.2 m hump, like a water bar or a low berm across a dirt road. The paper's Fig. 5 needs
# the shock to grow with speed over 5-15 m/s, and with the shock filter removing 0-10 Hz that
# holds only for an obstacle about this long: over a 0.5 m ridge the shock stops growing
# above about 10 m/s (it lasts 33 ms at 15 m/s, less than half a wheel-hop period, and the
# wheel cannot follow; peaks 0.22 / 0.37 / 0.39 / 0.33 / 0.30 G, r^2 0.08), while over a
# 1.5 m one the slow passes barely reach the filter's band (0.03 G at 5 m/s). The line does
# not pass through the origin (calibration seed 1: 0.068 G per m/s, -0.27 G): below
# v = 10 Hz x the obstacle's length its shock lies mostly under the filter's band.
FIXED_FEATURE_LENGTH_M = 1.2


@dataclass(frozen=True)
class RoughFeature:
    """One discrete rough feature; its first seven fields are published on the ground-truth
    topic (``terrain_msgs/RoughFeature``).

    ``s_start_m``..``s_end_m`` and ``d_center_m -+ width_m / 2`` are the feature's bounding
    box in route coordinates (for a rotated ellipse, the box around it), so a point outside
    the box is never on the feature. ``height_m`` is the height (rock, ridge, cattle-guard
    deck), depth (pothole, rut) or peak-to-peak amplitude (washboard). Rocks and potholes
    are ellipses: ``major_axis_m`` and ``minor_axis_m`` their full axes and ``yaw_rad`` the
    long axis's angle from the route's direction (+s) towards +d; zero axes (features made
    by hand) mean the ellipse inscribed in the bounding box.
    """

    kind: str
    s_start_m: float
    s_end_m: float
    d_center_m: float
    width_m: float
    height_m: float
    wavelength_m: float = 0.0
    major_axis_m: float = 0.0
    minor_axis_m: float = 0.0
    yaw_rad: float = 0.0


def _ellipse_frame(f: RoughFeature) -> tuple[float, float, float, float, float]:
    """(s of the centre, semi-major and semi-minor axis, cos and sin of the yaw) of a rock's
    or pothole's elliptical footprint."""
    sc = 0.5 * (f.s_start_m + f.s_end_m)
    if f.major_axis_m > 0.0 and f.minor_axis_m > 0.0:
        return sc, f.major_axis_m / 2, f.minor_axis_m / 2, np.cos(f.yaw_rad), np.sin(f.yaw_rad)
    return sc, (f.s_end_m - f.s_start_m) / 2, f.width_m / 2, 1.0, 0.0


def _ellipse_half_extents(a_m: float, b_m: float, yaw_rad: float) -> tuple[float, float]:
    """Half extents along s and d of an ellipse with semi-axes ``a_m``, ``b_m`` whose
    ``a`` axis is turned by ``yaw_rad`` from +s towards +d."""
    c, sn = np.cos(yaw_rad), np.sin(yaw_rad)
    return float(np.hypot(a_m * c, b_m * sn)), float(np.hypot(a_m * sn, b_m * c))


def feature_height(f: RoughFeature, s: FloatArray, d: FloatArray) -> FloatArray:
    """Height added by feature ``f`` at route coordinates ``s``, ``d`` (arrays that
    broadcast; the result has their broadcast shape), metres."""
    half_w = f.width_m / 2
    lateral = np.clip(1 - ((d - f.d_center_m) / half_w) ** 2, 0, 1) ** 0.25
    length = f.s_end_m - f.s_start_m
    u = (s - f.s_start_m) / length  # 0..1 along the feature
    inside = (u >= 0) & (u <= 1)
    if f.kind == "washboard":
        # Corrugations across the road, faded in and out over two wavelengths.
        ramp = np.clip(np.minimum(u, 1 - u) * length / (2 * f.wavelength_m), 0, 1)
        wave = 0.5 * f.height_m * np.sin(2 * np.pi * (s - f.s_start_m) / f.wavelength_m)
        return np.where(inside, wave * ramp * lateral, 0.0)
    if f.kind in ("pothole", "rock"):
        # r2: squared elliptical radius in the footprint's own axes, 1 on its edge.
        sc, a, b, c, sn = _ellipse_frame(f)
        ds = s - sc
        dd = d - f.d_center_m
        r2 = ((ds * c + dd * sn) / a) ** 2 + ((dd * c - ds * sn) / b) ** 2
        if f.kind == "rock":
            # The upper half of an ellipsoid: vertical flanks at the edge, a dome on top.
            return f.height_m * np.sqrt(np.maximum(1.0 - r2, 0.0))
        # A vertical wall at the rim, then a paraboloid bowl down to the full depth.
        wall = FEATURE_POTHOLE_WALL_FRACTION
        return np.where(r2 < 1.0, -f.height_m * (wall + (1.0 - wall) * (1.0 - r2)), 0.0)
    if f.kind == "ridge":
        # A smooth ridge across the road (a calibration obstacle, like a log or kerb).
        bump = np.where(inside, np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
        ridge: FloatArray = f.height_m * bump * lateral
        return ridge
    if f.kind == "rut":
        ramp = np.clip(np.minimum(u, 1 - u) * length / 2.0, 0, 1)
        groove = np.clip(1 - ((d - f.d_center_m) / half_w) ** 2, 0, 1)
        return np.where(inside, -f.height_m * groove * ramp, 0.0)
    if f.kind == "cattle_guard":
        # A raised deck of steel rails with gaps between them, across the whole road.
        ramp = np.clip(np.minimum(u, 1 - u) * length / 0.25, 0, 1)
        rails = 0.3 * (0.5 + 0.5 * np.cos(2 * np.pi * (s - f.s_start_m) / f.wavelength_m))
        return np.where(inside, f.height_m * ramp * (0.7 + rails) * lateral, 0.0)
    raise ValueError(f"unknown rough feature kind {f.kind!r}")


def footprint_lateral_span(f: RoughFeature, s_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The lateral extent ``(d_lo_m, d_hi_m)`` of feature ``f``'s footprint (where it
    changes the ground) at each of the distances ``s_m`` (any shape; both results have its
    shape), NaN where the footprint does not reach that ``s``.

    Rocks and potholes are their ellipses; every other kind its bounding box.
    """
    s = np.asarray(s_m, dtype=np.float64)
    if f.kind in ("pothole", "rock"):
        sc, a, b, c, sn = _ellipse_frame(f)
        x = s - sc
        # The ellipse's points (x, y = d - d_center) satisfy q2 y^2 + q1 y + q0 <= 0.
        q2 = (sn / a) ** 2 + (c / b) ** 2
        q1 = 2.0 * x * c * sn * (1.0 / a**2 - 1.0 / b**2)
        q0 = x * x * ((c / a) ** 2 + (sn / b) ** 2) - 1.0
        disc = q1 * q1 - 4.0 * q2 * q0
        root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        return f.d_center_m + (-q1 - root) / (2 * q2), f.d_center_m + (-q1 + root) / (2 * q2)
    inside = (s >= f.s_start_m) & (s <= f.s_end_m)
    half_w = f.width_m / 2
    lo = np.where(inside, f.d_center_m - half_w, np.nan)
    return lo, np.where(inside, f.d_center_m + half_w, np.nan)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _side(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _ellipse_feature(
    kind: str,
    s0_m: float,
    rng: np.random.Generator,
    height_range_m: tuple[float, float],
    half_road_m: float,
    track_m: float,
) -> RoughFeature:
    """A rock or pothole starting at ``s0_m``: footprint, orientation, height or depth and
    lateral place drawn from the distributions stated with the ``FEATURE_*`` constants."""
    rock = kind == "rock"
    major_range = FEATURE_ROCK_MAJOR_AXIS_RANGE_M if rock else FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M
    ratio_range = FEATURE_ROCK_AXIS_RATIO_RANGE if rock else FEATURE_POTHOLE_AXIS_RATIO_RANGE
    major = _log_uniform(rng, *major_range)
    minor = major * float(rng.uniform(*ratio_range))
    yaw = float(rng.uniform(0.0, np.pi))
    h_lo, h_hi = height_range_m
    if rock:
        # Exposed height at most the short horizontal axis (the rock lies on its largest
        # face); a profile's lower bound wins over that cap if the two conflict.
        h_hi = max(min(h_hi, minor), h_lo)
    height = _log_uniform(rng, h_lo, h_hi)
    half_s, half_d = _ellipse_half_extents(major / 2, minor / 2, yaw)
    outer = half_road_m + FEATURE_SHOULDER_WIDTH_M
    u = rng.random()
    if u < (FEATURE_ROCK_WHEEL_PATH_SHARE if rock else FEATURE_POTHOLE_WHEEL_PATH_SHARE):
        d = _side(rng) * track_m / 2 + rng.normal(0.0, FEATURE_WHEEL_PATH_SIGMA_M)
    elif not rock:
        d = rng.uniform(-(half_road_m - half_d), half_road_m - half_d)
    elif u < FEATURE_ROCK_WHEEL_PATH_SHARE + FEATURE_ROCK_EDGE_SHARE:
        d = _side(rng) * rng.uniform(half_road_m - FEATURE_ROCK_EDGE_INSET_M, outer - half_d)
    else:
        d = rng.uniform(-(outer - half_d), outer - half_d)
    return RoughFeature(
        kind,
        s0_m,
        s0_m + 2 * half_s,
        float(d),
        2 * half_d,
        height,
        major_axis_m=major,
        minor_axis_m=minor,
        yaw_rad=yaw,
    )


def make_features(
    params: WorldParams, route: Route, rng: np.random.Generator, track_m: float = 1.65
) -> tuple[RoughFeature, ...]:
    """Scatter discrete rough features along the road: Poisson in ``s`` at
    ``params.feature_rate_per_km``, kinds in the proportions of :data:`FEATURE_KIND_WEIGHTS`
    (among ``params.feature_kinds``), heights log-uniform in each kind's range clipped to
    ``params.feature_height_range_m`` (small features are much more common than large
    ones), then the profile's fixed features. Sorted by ``s_start_m``.

    Across the road (``track_m``: the track of the traffic that wears the road, 1.65 m like
    the simulated vehicle's):

    * potholes: in a traffic wheel path (``+-track_m / 2``, normal spread
      :data:`FEATURE_WHEEL_PATH_SIGMA_M`) with probability
      :data:`FEATURE_POTHOLE_WHEEL_PATH_SHARE`, else uniform over the road;
    * rocks: in a wheel path with probability :data:`FEATURE_ROCK_WHEEL_PATH_SHARE`, in
      the edge bands (:data:`FEATURE_ROCK_EDGE_INSET_M` inside each edge out to the
      shoulder's outer side) with probability :data:`FEATURE_ROCK_EDGE_SHARE`, else
      uniform over road and shoulders (:data:`FEATURE_SHOULDER_WIDTH_M` each side);
    * ruts: in a wheel path, as potholes there (wheels make them);
    * washboard and cattle guards: across the whole road.

    Rock and pothole footprints are ellipses (sizes and shapes with the ``FEATURE_*``
    constants); every footprint stays on the road and its shoulders.
    """
    count = rng.poisson(params.feature_rate_per_km * params.length_m / 1000.0)
    starts = np.sort(rng.uniform(30.0, max(params.length_m - 30.0, 31.0), size=count))
    lo, hi = params.feature_height_range_m
    kinds = params.feature_kinds
    unknown = [k for k in kinds if k not in FEATURE_KIND_WEIGHTS]
    if unknown:
        raise ValueError(f"no random placement for rough feature kinds {unknown}")
    weights = np.array([FEATURE_KIND_WEIGHTS[k] for k in kinds])
    weights = weights / weights.sum()
    out: list[RoughFeature] = []
    half_road = params.road_half_width_m
    for s0 in starts:
        kind = kinds[int(rng.choice(len(kinds), p=weights))]
        k_lo, k_hi = FEATURE_HEIGHT_RANGE_M[kind]
        h_lo, h_hi = max(lo, k_lo), max(min(hi, k_hi), max(lo, k_lo))
        if kind in ("pothole", "rock"):
            out.append(_ellipse_feature(kind, s0, rng, (h_lo, h_hi), half_road, track_m))
            continue
        height = _log_uniform(rng, h_lo, h_hi)
        if kind == "washboard":
            wavelength = float(rng.uniform(0.4, 1.0))
            length = float(rng.uniform(3.0, 12.0))
            out.append(RoughFeature(kind, s0, s0 + length, 0.0, 2 * half_road, height, wavelength))
        elif kind == "rut":
            length = float(rng.uniform(8.0, 40.0))
            width = float(rng.uniform(0.25, 0.5))
            d = _side(rng) * track_m / 2 + rng.normal(0.0, FEATURE_WHEEL_PATH_SIGMA_M)
            out.append(RoughFeature(kind, s0, s0 + length, float(d), width, height))
        else:  # cattle guard
            length = float(rng.uniform(2.0, 3.0))
            out.append(RoughFeature(kind, s0, s0 + length, 0.0, 2 * half_road, height, 0.2))
    for kind, s_center, height in params.fixed_features:
        size = FIXED_FEATURE_LENGTH_M
        out.append(
            RoughFeature(kind, s_center - size / 2, s_center + size / 2, 0.0, 2 * half_road, height)
        )
    out.sort(key=lambda f: f.s_start_m)
    return tuple(out)

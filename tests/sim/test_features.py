"""Rough features placed and sized like a desert road (issue 11).

Over a long route the stated distributions of :mod:`toolkit.sim.features` hold (kinds, lateral
mixtures, footprints, heights; each checked against the constants it is drawn from); rocks
and potholes have different shapes; the published bounding box holds every footprint; and
on a 6 km ``race`` world some features are met by one wheel of the driven path, some by
both, and many are missed (from the geometry alone: the driven path, the track and the
tyre width).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from toolkit.sim.drive import make_driven_path
from toolkit.sim.features import (
    FEATURE_HEIGHT_RANGE_M,
    FEATURE_KIND_WEIGHTS,
    FEATURE_POTHOLE_AXIS_RATIO_RANGE,
    FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M,
    FEATURE_POTHOLE_WALL_FRACTION,
    FEATURE_POTHOLE_WHEEL_PATH_SHARE,
    FEATURE_ROCK_AXIS_RATIO_RANGE,
    FEATURE_ROCK_EDGE_INSET_M,
    FEATURE_ROCK_EDGE_SHARE,
    FEATURE_ROCK_MAJOR_AXIS_RANGE_M,
    FEATURE_ROCK_WHEEL_PATH_SHARE,
    FEATURE_SHOULDER_WIDTH_M,
    FEATURE_WHEEL_PATH_SIGMA_M,
    RoughFeature,
    feature_height,
    footprint_lateral_span,
    make_features,
)
from toolkit.sim.profiles import make_profile
from toolkit.sim.route import make_route
from toolkit.sim.world import make_world
from toolkit.sim.world_params import WorldParams

SEED = 11  # no other test uses it
TRACK_M = 1.65
# Tyre section width for "met by a wheel": a 255 mm tyre (the Touareg's 255/55 R18 size;
# judgement, the vehicle model's tyres have no width of their own here).
TYRE_WIDTH_M = 0.255
# Share of a normal distribution within one standard deviation of its mean.
WITHIN_ONE_SIGMA = 0.6826894921370859


@pytest.fixture(scope="module")
def many() -> tuple[WorldParams, tuple[RoughFeature, ...]]:
    """About 2000 features on a 40 km race road (the race profile's height range)."""
    params = replace(make_profile("race").world, length_m=40_000.0, feature_rate_per_km=50.0)
    route = make_route(params, np.random.default_rng([SEED, 0]))
    return params, make_features(params, route, np.random.default_rng([SEED, 3]), TRACK_M)


def _of(features: tuple[RoughFeature, ...], kind: str) -> list[RoughFeature]:
    return [f for f in features if f.kind == kind]


def _uniform_ks(values: np.ndarray, lo: float, hi: float) -> float:
    """KS p-value of ``values`` against the uniform distribution on [lo, hi]."""
    return float(stats.kstest(values, stats.uniform(lo, hi - lo).cdf).pvalue)


# --------------------------------------------------------------------------------------
# Distributions


def test_kinds_in_the_stated_proportions(
    many: tuple[WorldParams, tuple[RoughFeature, ...]],
) -> None:
    params, feats = many
    counts = Counter(f.kind for f in feats)
    n = len(feats)
    assert n == pytest.approx(params.feature_rate_per_km * params.length_m / 1000, rel=0.1)
    total = sum(FEATURE_KIND_WEIGHTS[k] for k in params.feature_kinds)
    for kind in params.feature_kinds:
        p = FEATURE_KIND_WEIGHTS[kind] / total
        se = np.sqrt(p * (1 - p) / n)
        assert abs(counts[kind] / n - p) < 4 * se, (kind, counts[kind], n, p)


def test_rock_and_pothole_sizes_follow_the_stated_distributions(
    many: tuple[WorldParams, tuple[RoughFeature, ...]],
) -> None:
    """Long axes log-uniform, axis ratios and yaw uniform, pothole depths log-uniform in
    the kind's range; rock heights log-uniform too where the short-axis cap is inactive,
    and never above the short axis."""
    params, feats = many
    for kind, major_range, ratio_range in (
        ("rock", FEATURE_ROCK_MAJOR_AXIS_RANGE_M, FEATURE_ROCK_AXIS_RATIO_RANGE),
        ("pothole", FEATURE_POTHOLE_MAJOR_AXIS_RANGE_M, FEATURE_POTHOLE_AXIS_RATIO_RANGE),
    ):
        fs = _of(feats, kind)
        assert len(fs) > 400, kind
        major = np.array([f.major_axis_m for f in fs])
        ratio = np.array([f.minor_axis_m / f.major_axis_m for f in fs])
        yaw = np.array([f.yaw_rad for f in fs])
        lo, hi = major_range
        assert lo <= major.min() and major.max() <= hi
        assert np.median(major) == pytest.approx(np.sqrt(lo * hi), rel=0.08)
        assert _uniform_ks(np.log(major), np.log(lo), np.log(hi)) > 1e-3, kind
        assert _uniform_ks(ratio, *ratio_range) > 1e-3, kind
        assert np.mean(ratio) == pytest.approx(np.mean(ratio_range), abs=0.02)
        assert _uniform_ks(yaw, 0.0, np.pi) > 1e-3, kind
    # Heights: the kind's range clipped to the profile's.
    p_lo, p_hi = params.feature_height_range_m
    h_lo = max(p_lo, FEATURE_HEIGHT_RANGE_M["pothole"][0])
    h_hi = min(p_hi, FEATURE_HEIGHT_RANGE_M["pothole"][1])
    depth = np.array([f.height_m for f in _of(feats, "pothole")])
    assert h_lo <= depth.min() and depth.max() <= h_hi
    assert _uniform_ks(np.log(depth), np.log(h_lo), np.log(h_hi)) > 1e-3
    rocks = _of(feats, "rock")
    r_lo = max(p_lo, FEATURE_HEIGHT_RANGE_M["rock"][0])
    r_hi = min(p_hi, FEATURE_HEIGHT_RANGE_M["rock"][1])
    assert all(f.height_m <= f.minor_axis_m for f in rocks)
    assert all(r_lo <= f.height_m <= r_hi for f in rocks)
    uncapped = np.array([f.height_m for f in rocks if f.minor_axis_m >= r_hi])
    assert uncapped.size > 100
    assert _uniform_ks(np.log(uncapped), np.log(r_lo), np.log(r_hi)) > 1e-3
    # Potholes are wider than rocks, and shallower for their width.
    pothole_major = np.median([f.major_axis_m for f in _of(feats, "pothole")])
    assert pothole_major > 1.5 * np.median([f.major_axis_m for f in rocks])
    aspect_p = np.median([f.height_m / f.minor_axis_m for f in _of(feats, "pothole")])
    assert aspect_p < 0.7 * np.median([f.height_m / f.minor_axis_m for f in rocks])


def test_lateral_placement_follows_the_stated_mixtures(
    many: tuple[WorldParams, tuple[RoughFeature, ...]],
) -> None:
    """Potholes on the road and concentrated in the wheel paths; rocks on road and
    shoulders, many at the edges; each share against its expectation under the stated
    mixture given the features' own footprints (within 4 standard errors)."""
    params, feats = many
    half = params.road_half_width_m
    outer = half + FEATURE_SHOULDER_WIDTH_M
    band_lo, band_hi = (
        TRACK_M / 2 - FEATURE_WHEEL_PATH_SIGMA_M,
        (TRACK_M / 2 + FEATURE_WHEEL_PATH_SIGMA_M),
    )

    def check(share: np.ndarray, expected: np.ndarray, what: str) -> None:
        p = float(expected.mean())
        se = np.sqrt(p * (1 - p) / share.size)
        print(f"{what}: {share.mean():.3f} (expected {p:.3f} +- {se:.3f})")
        assert abs(share.mean() - p) < 4 * se, what

    potholes = _of(feats, "pothole")
    d = np.abs([f.d_center_m for f in potholes])
    hd = np.array([f.width_m / 2 for f in potholes])
    assert np.all(d + hd <= half + 1e-9), "a pothole off the road"
    # In a wheel path: one sigma of the normal part, plus the uniform part's share of the
    # two bands (each 2 sigma wide) over the road width left to the pothole's centre.
    in_band = (d > band_lo) & (d < band_hi)
    share_w = FEATURE_POTHOLE_WHEEL_PATH_SHARE
    expected = share_w * WITHIN_ONE_SIGMA + (1 - share_w) * (
        2 * FEATURE_WHEEL_PATH_SIGMA_M / (half - hd)
    )
    check(in_band, expected, "potholes within a sigma of a wheel path")

    rocks = _of(feats, "rock")
    d = np.abs([f.d_center_m for f in rocks])
    hd = np.array([f.width_m / 2 for f in rocks])
    assert np.all(d + hd <= outer + 1e-9), "a rock off the shoulders"
    assert np.mean(d > half) > 0.2, "rocks on the shoulders"
    uniform = 1 - FEATURE_ROCK_WHEEL_PATH_SHARE - FEATURE_ROCK_EDGE_SHARE
    edge_lo = half - FEATURE_ROCK_EDGE_INSET_M
    check(
        d > edge_lo,
        FEATURE_ROCK_EDGE_SHARE + uniform * (outer - hd - edge_lo) / (outer - hd),
        "rocks at the edges",
    )
    check(
        (d > band_lo) & (d < band_hi),
        FEATURE_ROCK_WHEEL_PATH_SHARE * WITHIN_ONE_SIGMA
        + uniform * 2 * FEATURE_WHEEL_PATH_SIGMA_M / (outer - hd),
        "rocks within a sigma of a wheel path",
    )
    # Ruts are wheel paths; washboard and cattle guards span the road.
    d = np.abs([f.d_center_m for f in _of(feats, "rut")])
    assert np.mean((d > band_lo) & (d < band_hi)) == pytest.approx(WITHIN_ONE_SIGMA, abs=0.1)
    for f in _of(feats, "washboard") + _of(feats, "cattle_guard"):
        assert f.d_center_m == 0.0 and f.width_m == 2 * half


# --------------------------------------------------------------------------------------
# Shapes and the published footprint


def _pair(major_m: float, minor_m: float, height_m: float, yaw_rad: float) -> list[RoughFeature]:
    return [
        RoughFeature(
            kind, 10.0, 10.0 + major_m, 0.0, minor_m, height_m, 0.0, major_m, minor_m, yaw_rad
        )
        for kind in ("rock", "pothole")
    ]


def test_a_rock_and_a_pothole_of_equal_size_differ_in_shape() -> None:
    """A rock is a bump whose flank rises steeply from its edge; a pothole of the same
    footprint and height is a drop over a vertical rim into a rounded bowl, not the rock's
    mirror image."""
    rock, pothole = _pair(0.4, 0.3, 0.1, 0.0)
    s = 10.2 + np.linspace(-0.2, 0.2, 4001)  # along the long axis through the centre
    zr = feature_height(rock, s, np.zeros_like(s))
    zp = feature_height(pothole, s, np.zeros_like(s))
    assert zr.max() == pytest.approx(0.1, rel=1e-3) and zr.min() >= 0.0
    assert zp.min() == pytest.approx(-0.1, rel=1e-3) and zp.max() <= 0.0
    # The rim: just inside the edge the pothole is already half its depth down; the rock
    # rises to 44 % of its height over the outer 10 % of its radius (vertical at the edge).
    edge = np.abs(s - 10.2) > 0.2 * 0.999
    assert zp[~edge][0] <= -FEATURE_POTHOLE_WALL_FRACTION * 0.1 * 0.999
    inner = np.abs(s - 10.2) <= 0.2 * 0.9
    assert zr[inner][0] == pytest.approx(0.1 * np.sqrt(1 - 0.9**2), rel=0.01)
    # Not mirror images: the two differ by 30 % of the height somewhere.
    assert np.max(np.abs(zr + zp)) > 0.3 * 0.1


def test_feature_height_is_vectorised_and_zero_outside_the_bounding_box(
    many: tuple[WorldParams, tuple[RoughFeature, ...]],
) -> None:
    """The truth check (``toolkit/stages/label_truth.py``) takes the published box
    ``[s_start, s_end] x [d_center -+ width / 2]`` as the footprint: no height outside it,
    and the ellipse touches all four sides (the box is tight)."""
    _, feats = many
    for f in [*_of(feats, "rock")[:60], *_of(feats, "pothole")[:60]]:
        s = np.linspace(f.s_start_m - 0.1, f.s_end_m + 0.1, 241)
        d = np.linspace(f.d_center_m - f.width_m / 2 - 0.1, f.d_center_m + f.width_m / 2 + 0.1, 243)
        z = feature_height(f, s[:, None], d[None, :])
        assert z.shape == (s.size, d.size)
        # One point at a time gives the same (the grid is just broadcasting).
        k = [(7, 100), (120, 121), (200, 30)]
        for i, j in k:
            assert z[i, j] == feature_height(f, np.array(s[i]), np.array(d[j]))
        in_box = ((s >= f.s_start_m) & (s <= f.s_end_m))[:, None] & (
            np.abs(d - f.d_center_m) <= f.width_m / 2
        )[None, :]
        assert not np.any(z[~in_box]), f
        assert np.any(z[in_box]), f
        s_fine = np.linspace(f.s_start_m, f.s_end_m, 20001)
        lo, hi = footprint_lateral_span(f, s_fine)
        assert np.nanmin(lo) == pytest.approx(f.d_center_m - f.width_m / 2, abs=1e-6)
        assert np.nanmax(hi) == pytest.approx(f.d_center_m + f.width_m / 2, abs=1e-6)
        ok = ~np.isnan(lo)
        assert s_fine[ok][0] - f.s_start_m < 0.01 and f.s_end_m - s_fine[ok][-1] < 0.01


def test_footprint_span_is_where_the_ground_changes(
    many: tuple[WorldParams, tuple[RoughFeature, ...]],
) -> None:
    """Inside the span a rock or pothole changes the ground; 1 mm outside it, not."""
    _, feats = many
    for f in [*_of(feats, "rock")[:50], *_of(feats, "pothole")[:50]]:
        s = np.linspace(f.s_start_m, f.s_end_m, 51)[1:-1]
        lo, hi = footprint_lateral_span(f, s)
        assert not np.isnan(lo).any()
        mid = 0.5 * (lo + hi)
        assert np.all(feature_height(f, s, mid) != 0.0)
        assert np.all(feature_height(f, s, lo + 1e-3) != 0.0)
        assert np.all(feature_height(f, s, lo - 1e-3) == 0.0)
        assert np.all(feature_height(f, s, hi + 1e-3) == 0.0)


def test_features_are_deterministic_for_a_seed() -> None:
    params = make_profile("race", 3000.0).world
    route = make_route(params, np.random.default_rng([SEED, 0]))
    a = make_features(params, route, np.random.default_rng([SEED, 3]))
    b = make_features(params, route, np.random.default_rng([SEED, 3]))
    c = make_features(params, route, np.random.default_rng([SEED + 1, 3]))
    assert a == b and a != c
    s, d = np.meshgrid(np.arange(0.0, 3000.0, 0.5), np.linspace(-5, 5, 21), indexing="ij")
    za = sum(feature_height(f, s, d) for f in a)
    zb = sum(feature_height(f, s, d) for f in b)
    np.testing.assert_array_equal(za, zb)


# --------------------------------------------------------------------------------------
# Met by the wheels of the driven path


def wheels_meeting(
    f: RoughFeature, s_path_m: np.ndarray, wander_m: np.ndarray, track_m: float
) -> int:
    """How many of the two wheels (0, 1 or 2) of a vehicle on the driven path (lateral
    offset ``wander_m`` of its centre at ``s_path_m``) have their tyre's contact strip
    (``TYRE_WIDTH_M`` wide) overlap the feature's footprint somewhere along it."""
    s = np.arange(f.s_start_m, f.s_end_m + 1e-9, 0.01)
    lo, hi = footprint_lateral_span(f, s)
    centre = np.interp(s, s_path_m, wander_m)
    met = 0
    for sign in (1.0, -1.0):
        wheel = centre + sign * track_m / 2
        met += bool(np.any((lo <= wheel + TYRE_WIDTH_M / 2) & (hi >= wheel - TYRE_WIDTH_M / 2)))
    return met


def test_on_a_race_some_features_are_met_by_one_wheel_some_by_both_many_missed() -> None:
    """On a 6 km race world, per kind: count per km and the wheels that meet it."""
    prof = make_profile("race", 6000.0)
    world = make_world(prof.world, SEED)
    path = make_driven_path(world.route, np.random.default_rng([SEED, 4]), prof.lane_wander_m)
    track = prof.vehicle.track_m
    table: dict[str, Counter[int]] = {}
    for f in world.features:
        table.setdefault(f.kind, Counter())[wheels_meeting(f, path.s_m, path.wander_m, track)] += 1
    km = prof.world.length_m / 1000
    print()
    for kind, c in sorted(table.items()):
        n = sum(c.values())
        print(f"{kind:13s} {n / km:5.2f}/km  one {c[1]:3d}  both {c[2]:3d}  missed {c[0]:3d}")
    total: Counter[int] = sum(table.values(), Counter())
    n = sum(total.values())
    met = (total[1] + total[2]) / n
    print(
        f"{'all':13s} {n / km:5.2f}/km  one {total[1]:3d}  both {total[2]:3d}  "
        f"missed {total[0]:3d}  met {met:.2f}"
    )
    # Over seeds 1-30 the share met is 0.49-0.70 (mean 0.61): well below today's 0.9.
    assert 0.35 <= met <= 0.75
    # Missed and met by one wheel are the common cases; met by both (washboard, cattle guards
    # and wide potholes span the track) the rarer one.
    assert min(total[0], total[1]) >= 0.1 * n and total[2] >= 0.05 * n
    for kind in ("rock", "pothole"):
        c = table[kind]
        assert sum(c.values()) >= 10, kind
        assert c[1] >= 2 and c[0] >= 2, (kind, c)  # some met by a wheel, some missed
    # Rocks lie mostly off the wheels' strips, potholes mostly on them.
    rock_met = 1 - table["rock"][0] / sum(table["rock"].values())
    pothole_met = 1 - table["pothole"][0] / sum(table["pothole"].values())
    assert rock_met < 0.5 < pothole_met

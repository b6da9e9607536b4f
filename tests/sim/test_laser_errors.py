"""Each of the lasers' error sources is there, of the size ``LaserParams`` states.

Unit checks on a synthetic straight road (the beam footprint, mixed pixels at a depth edge),
on the error model fed exact ranges (bias, noise, quantisation, dust) and on the per-seed
draws (miscalibrated mounts); the log-level ones (stamp jitter, mount flex, metadata) are in
``test_laser_truth.py`` next to the projection they need.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from toolkit.sim.laser_workers import LaserRays
from toolkit.sim.profiles import make_profile
from toolkit.sim.raycast import RayCaster
from toolkit.sim.route import Route
from toolkit.sim.sensors import LaserParams, draw_laser_truth, ideal_lasers
from toolkit.sim.suite import SensorSuite
from toolkit.sim.terrain import Grid, TerrainWindow
from toolkit.sim.world import make_world

SENSOR_HEIGHT_M = 2.0
DIVERGENCE_RAD = LaserParams().beam_divergence_rad
HALF_RAD = 0.5 * DIVERGENCE_RAD


# -- a straight, level road along x, with a height profile in s only ----------------------


def _straight_route(length_m: float = 120.0) -> Route:
    s = np.arange(0.0, length_m + 1.0, 1.0)
    zero = np.zeros_like(s)
    return Route(s, s.copy(), zero, zero.copy(), zero.copy(), zero.copy(), np.full(s.size, 10.0))


def _window(height: Callable[[np.ndarray], np.ndarray]) -> TerrainWindow:
    """Heights on a 1 cm grid along the road (constant across it)."""
    ds = 0.01
    s = np.arange(12_000) * ds
    d = np.arange(-6.0, 6.0 + 1e-9, 0.5)
    fine = Grid(0.0, -6.0, ds, 0.5, np.repeat(height(s)[:, None], d.size, axis=1))
    coarse = Grid(0.0, -45.0, 1.0, 1.0, np.zeros((120, 91)))
    return TerrainWindow(fine, coarse, 6.0)


def _fan(x_lo: float, x_hi: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from (0, 0, 2 m) along +x aimed at level ground from x_lo to x_hi: origins,
    directions (n, 3) and depression angles (n,)."""
    x = np.linspace(x_lo, x_hi, n)
    dep = np.arctan2(SENSOR_HEIGHT_M, x)
    u = np.stack([np.cos(dep), np.zeros(n), -np.sin(dep)], axis=1)
    return np.tile([0.0, 0.0, SENSOR_HEIGHT_M], (n, 1)), u, dep


ROUTE = _straight_route()


def _level(d: np.ndarray) -> np.ndarray:
    return np.zeros_like(d)


# The ideal caster, marching in 2 mm steps of descent (not the default 0.1 m: a grazing ray
# that dips under a plateau's level for less than one step before its edge is not seen to).
EXACT_STEP_DZ_M = 0.002
EXACT = RayCaster(ROUTE, _level, step_dz_m=EXACT_STEP_DZ_M)
FOOTPRINT = RayCaster(
    ROUTE,
    _level,
    divergence_rad=DIVERGENCE_RAD,
    footprint_samples=LaserParams().footprint_samples,
    footprint_spacing_m=LaserParams().footprint_spacing_m,
    occluder_samples=LaserParams().occluder_samples,
    occluder_spacing_m=LaserParams().occluder_spacing_m,
    occluder_height_m=LaserParams().occluder_height_m,
)


def test_footprint_on_level_ground_returns_about_the_centre_range() -> None:
    """On a plane the cone's mean range is its centre ray's, plus a little because range
    grows faster than linearly with elevation: (1/3) (half / el)^2 of the range for a cone
    uniform in angle (6 mm at 25 m from 2 m up)."""
    win = _window(np.zeros_like)
    o, u, dep = _fan(8.0, 25.0, 18)
    exact = EXACT.cast(win, o, u, 15.0)
    mean = FOOTPRINT.cast(win, o, u, 15.0)
    np.testing.assert_allclose(exact, SENSOR_HEIGHT_M / np.sin(dep), atol=1e-3)
    expected = exact * (HALF_RAD / dep) ** 2 / 3
    print(f"\nfootprint - centre range at 8..25 m: {(mean - exact)[[0, -1]]} m")
    np.testing.assert_allclose(mean - exact, expected, atol=1.5e-3)


@pytest.mark.parametrize("edge_m", [10.0, 25.0])
def test_footprint_grows_with_range(edge_m: float) -> None:
    """A 5 cm step up across the road at ``edge_m``: the returns that differ from the centre
    ray's (beyond the level-ground offset) are those whose footprint covers the step, so the
    ground they span is the footprint's length, ``H / tan(el - half) - H / tan(el + half)``:
    0.23 m at 10 m, 1.37 m at 25 m (range^2 x divergence / height)."""
    win = _window(lambda s: np.where(s >= edge_m, 0.05, 0.0))
    level = _window(np.zeros_like)
    o, u, dep = _fan(edge_m - 3.0, edge_m + 3.0, 3001)
    exact = EXACT.cast(win, o, u, edge_m)
    offset = FOOTPRINT.cast(level, o, u, edge_m) - EXACT.cast(level, o, u, edge_m)
    differs = np.abs(FOOTPRINT.cast(win, o, u, edge_m) - exact - offset) > 0.005
    ground = exact * np.cos(dep)
    width = float(np.ptp(ground[differs]))
    el = math.atan2(SENSOR_HEIGHT_M, edge_m)
    length = SENSOR_HEIGHT_M / math.tan(el - HALF_RAD) - SENSOR_HEIGHT_M / math.tan(el + HALF_RAD)
    print(f"\nstep at {edge_m} m: returns differ over {width:.3f} m; footprint {length:.3f} m")
    # The rays whose footprint puts only a sliver on the step differ by less than 5 mm.
    assert 0.5 * length < width < 1.1 * length
    assert ground[differs].min() > edge_m - 1.1 * length
    assert ground[differs].max() < edge_m + 1.1 * length


def test_mixed_pixels_at_a_depth_edge() -> None:
    """A 0.1 m plateau (a rock's height) ending at x = 16 m, level ground beyond: from 2 m up
    the edge casts a shadow to 16.84 m. The exact centre ray lands on the plateau or beyond
    the shadow, never in it. The footprint's return lands in the shadow (between the two
    surfaces: a mixed pixel) only when the cone straddles the edge; a straddling cone
    returns a mixed range or one of the surfaces (the edge is resolved to the spacing of the
    footprint's samples: a third of them mix here)."""
    edge, top = 16.0, 0.1
    win = _window(lambda s: np.where((s >= 5.0) & (s < edge), top, 0.0))
    shadow_end = edge * SENSOR_HEIGHT_M / (SENSOR_HEIGHT_M - top)
    o, u, dep = _fan(15.0, 20.0, 2001)
    exact = EXACT.cast(win, o, u, 15.0)
    mixed = FOOTPRINT.cast(win, o, u, 15.0)
    cos = np.cos(dep)

    def in_shadow(r: np.ndarray) -> np.ndarray:
        ground = r * cos
        return (ground > edge + 0.02) & (ground < shadow_end - 0.02)

    off = dep - math.atan2(SENSOR_HEIGHT_M - top, edge)  # > 0: the centre ray hits the top
    # (The exact ray may step over the plateau where it dips under its level by less than
    # a step or two of the march before the edge (whose last cm the grid blurs): offsets
    # below 2 step / edge.)
    assert not in_shadow(exact)[np.abs(off) > 2 * EXACT_STEP_DZ_M / edge].any()
    straddles = np.abs(off) < HALF_RAD
    hit = in_shadow(mixed)
    print(
        f"\n{straddles.sum()} rays straddle the edge; {hit.sum()} mixed returns, at cone "
        f"offsets {np.degrees(off[hit]).min():.3f} .. {np.degrees(off[hit]).max():.3f} deg"
    )
    assert hit[straddles].mean() > 0.25
    assert not hit[~straddles].any()
    # A straddling return lies between the nearest the cone meets the plateau (its lowest
    # sub-ray) and the farthest it meets the ground behind (its highest); off the edge by
    # more than the cone, the return is the surface's.
    near = (SENSOR_HEIGHT_M - top) / np.sin(dep + HALF_RAD)
    far = SENSOR_HEIGHT_M / np.sin(dep - HALF_RAD)
    assert np.all((mixed[straddles] > near[straddles]) & (mixed[straddles] < far[straddles]))
    clear = np.abs(off) > HALF_RAD
    np.testing.assert_allclose(mixed[clear], exact[clear], atol=0.04)


# -- the per-seed draws --------------------------------------------------------------------


def test_true_mounts_differ_from_the_published_ones_by_the_stated_amount() -> None:
    """Over 200 seeds: each laser's pitch and roll error is the rack's common one (magnitude
    within ``rack_angle_error_rad``) plus its own (within +-``laser_angle_error_rad``), yaw
    its own only, position within +-``mount_xyz_error_m`` per axis; the bias within
    +-``range_bias_max_m``. The same seed draws the same; another seed another."""
    p = LaserParams()
    lo, hi = p.rack_angle_error_rad
    own = p.laser_angle_error_rad
    rpy, xyz, bias = [], [], []
    for seed in range(200):
        truth = draw_laser_truth(p, seed)
        assert truth == draw_laser_truth(p, seed)
        rpy.append(
            [np.subtract(t.rpy_rad, m.rpy_rad) for t, m in zip(truth.mounts, p.mounts, strict=True)]
        )
        xyz.append(
            [np.subtract(t.xyz_m, m.xyz_m) for t, m in zip(truth.mounts, p.mounts, strict=True)]
        )
        bias.append(truth.range_bias_m)
        assert [m.frame_id for m in truth.mounts] == [m.frame_id for m in p.mounts]
    e = np.asarray(rpy)  # (seeds, lasers, 3)
    assert draw_laser_truth(p, 0) != draw_laser_truth(p, 1)
    # Roll and pitch: the lasers of one seed share the rack's error, so their mean is within
    # the rack's range (give or take their own errors' mean) and its sign is random.
    rack = e[:, :, :2].mean(axis=1)
    assert np.all(np.abs(rack) > lo - own) and np.all(np.abs(rack) < hi + own)
    assert 0.3 < (rack > 0).mean() < 0.7
    spread = e[:, :, :2] - e[:, :, :2].mean(axis=1, keepdims=True)
    assert np.abs(spread).max() < 2 * own
    assert np.abs(e[:, :, :2]).max() <= hi + own
    assert np.abs(e[:, :, 2]).max() <= own and np.abs(e[:, :, 2]).max() > 0.9 * own
    d = np.asarray(xyz)
    assert np.abs(d).max() <= p.mount_xyz_error_m and np.abs(d).max() > 0.95 * p.mount_xyz_error_m
    b = np.asarray(bias)
    assert np.abs(b).max() <= p.range_bias_max_m and b.std() == pytest.approx(
        p.range_bias_max_m / math.sqrt(3), rel=0.1
    )
    print(
        f"\npitch/roll error (deg): rack |mean| {np.degrees(np.abs(rack)).min():.3f} .. "
        f"{np.degrees(np.abs(rack)).max():.3f}, total max {np.degrees(np.abs(e)).max():.3f}"
    )


def test_ideal_lasers_switch_every_error_source_off() -> None:
    p = ideal_lasers(LaserParams())
    truth = draw_laser_truth(p, 7)
    assert truth.mounts == p.mounts and set(truth.range_bias_m) == {0.0}
    assert p.range_noise_m == LaserParams().range_noise_m
    assert p.beam_divergence_rad == 0.0 and p.flex_pitch_rad_per_mps2 == 0.0
    assert p.stamp_jitter_s == 0.0 and p.dust_onset_per_s == 0.0 and p.dropout_probability == 0


# -- the error model fed exact ranges ------------------------------------------------------


def _suite(laser: LaserParams, seed: int = 5) -> SensorSuite:
    prof = make_profile("sample", 200.0)
    prof = dataclasses.replace(prof, sensors=dataclasses.replace(prof.sensors, laser=laser))
    return SensorSuite(prof, make_world(prof.world, seed), seed, prof.start_time_ns)


def _rays(n_per_laser: int, speed_mps: float, lasers: int = 5) -> LaserRays:
    period = 1e9 / 75.0
    starts = np.repeat((np.arange(n_per_laser) * period).astype(np.int64), lasers)
    index = np.tile(np.arange(lasers), n_per_laser)
    n = starts.size * 181
    return LaserRays(
        starts_ns=starts,
        laser_index=index,
        speed_mps=np.full(starts.size, speed_mps),
        origin=np.zeros((n, 3)),
        direction=np.zeros((n, 3)),
        s_hint_m=0.0,
        s_lo_m=0.0,
        s_hi_m=0.0,
    )


def test_range_bias_noise_and_quantisation() -> None:
    """Exact ranges of 20 m come out as 20 m + the laser's bias (its mean, to 0.3 mm over
    360 000 beams), with the statistical noise (std 10 mm, plus the 1 cm count's 2.9 mm),
    in whole counts of 1 cm."""
    p = dataclasses.replace(LaserParams(), dust_onset_per_s=0.0, dropout_probability=0.0)
    suite = _suite(p)
    rays = _rays(2000, 10.0)
    out = suite.measured_ranges(rays, np.full(rays.starts_ns.size * 181, 20.0))
    assert out.dtype == np.float32 and out.shape == (rays.starts_ns.size, 181)
    counts = out.astype(np.float64) / p.range_resolution_m
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-3)
    bias = np.asarray(suite.laser_truth.range_bias_m)
    assert np.abs(bias).max() > 0.01  # this seed's biases are not all small
    for i in range(5):
        r = out[rays.laser_index == i].astype(np.float64)
        assert r.mean() - 20.0 == pytest.approx(bias[i], abs=3e-4), i
        assert r.std() == pytest.approx(math.hypot(0.010, 0.01 / math.sqrt(12)), rel=0.03), i


def test_dust_comes_in_bursts_and_more_at_speed() -> None:
    """Dust episodes start at 0.1 /s x speed / 10 m/s per laser and last 0.5 s on average:
    at 20 m/s a laser is in dust a fraction 0.1 x 2 x 0.5 / (1 + 0.1) = 9 % of its scans, at
    5 m/s 2.4 %. A dusty scan loses about half the beams of one sector 20-90 beams wide;
    consecutive scans share it (a burst), and dust is NaN."""
    p = dataclasses.replace(LaserParams(), dropout_probability=0.0)
    fractions = {}
    for speed in (5.0, 20.0):
        suite = _suite(p, seed=9)
        # Blocks of 8 scans per laser, as the simulator hands them over: 14 minutes of scans,
        # some 210 episodes over the five lasers at 5 m/s, so the dusty fraction (episodes
        # of exponential length) is known to about 10 % and the test below to 3.5 sigma.
        lost = np.concatenate(
            [
                suite.measured_ranges(r, np.full(r.starts_ns.size * 181, 20.0))
                for r in (_shifted(_rays(8, speed), k * 8) for k in range(8000))
            ]
        )
        assert not np.isinf(lost).any()
        nan = np.isnan(lost).reshape(-1, 5, 181)  # (scan, laser, beam)
        dusty = nan.any(axis=2)
        fractions[speed] = dusty.mean()
        # A dusty scan's lost beams sit in one sector, about half of it lost.
        width = np.array(
            [np.ptp(np.flatnonzero(row)) + 1 for row in nan.reshape(-1, 181)[dusty.ravel()]]
        )
        share = nan.reshape(-1, 181)[dusty.ravel()].sum(axis=1) / width
        assert width.max() <= p.dust_sector_beams[1]
        assert np.median(share) == pytest.approx(p.dust_drop_probability, abs=0.1)
        # Bursts: a dusty scan's successor is mostly dusty too (mean episode 37 scans).
        follows = dusty[1:][dusty[:-1]].mean()
        assert follows > 0.9
    expected = {v: 0.1 * v / 10 * 0.5 / (1 + 0.1 * v / 10 * 0.5) for v in (5.0, 20.0)}
    print(f"\ndusty scans: {fractions} (expected {expected})")
    for v in (5.0, 20.0):
        assert fractions[v] == pytest.approx(expected[v], rel=0.35)
    assert fractions[20.0] > 2.5 * fractions[5.0]


def _shifted(rays: LaserRays, scans: int) -> LaserRays:
    return dataclasses.replace(rays, starts_ns=rays.starts_ns + int(scans * 1e9 / 75.0))
